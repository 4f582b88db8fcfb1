# Two commands: `make demo` and `make test`. Each creates .venv when missing, installs
# the pinned dependencies (requirements.txt) plus this package, and builds the interface
# package mr_ident_msgs/ into .venv (again whenever one of its files changes).
VENV   := .venv
PY     := $(VENV)/bin/python
PIP_STAMP := $(VENV)/.installed
# everything installed: the pinned packages, this package and mr_ident_msgs
STAMP  := $(VENV)/.msgs_installed
export ROS_LOG_DIR ?= $(CURDIR)/out/ros_log
export MPLBACKEND := Agg

.PHONY: demo paper test test-numerics test-apt venv-apt test-apt-numpy lint docs colcon bench lrm-figure bench-structured bench-fit bench-missing bench-alias-range bench-setpoint bench-bag bench-live bench-diagnose bench-monitor soak motor-bench venv clean

venv: $(STAMP)

$(PIP_STAMP): requirements.txt setup.py setup.cfg
	@echo "setting up $(VENV): installing the pinned packages of requirements.txt and mr_ident, then building mr_ident_msgs: 1-2 minutes the first time" >&2
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.txt
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation --use-pep517 -e .
	touch $(PIP_STAMP)

# mr_ident_msgs (ament_cmake + rosidl) built with the ROS 2 wheels of .venv and installed
# into .venv itself (lib/, share/, site-packages), so nothing needs setting at run time.
# The files of the previous install go first (a removed interface leaves nothing behind).
MSGS_SRC   := mr_ident_msgs/CMakeLists.txt mr_ident_msgs/package.xml \
              $(wildcard mr_ident_msgs/msg/*.msg mr_ident_msgs/srv/*.srv)
MSGS_BUILD := $(VENV)/build/mr_ident_msgs
ROS_PREFIX := CMAKE_PREFIX_PATH=$(abspath $(VENV)) AMENT_PREFIX_PATH=$(abspath $(VENV))
$(STAMP): $(PIP_STAMP) $(MSGS_SRC)
	@echo "building the interfaces mr_ident_msgs into $(VENV) (under a minute)" >&2
	if [ -f $(MSGS_BUILD)/install_manifest.txt ]; then \
	  xargs rm -f < $(MSGS_BUILD)/install_manifest.txt; fi
	$(ROS_PREFIX) cmake -S mr_ident_msgs -B $(MSGS_BUILD) --log-level=WARNING \
	  -DCMAKE_INSTALL_PREFIX=$(abspath $(VENV)) -DPython3_EXECUTABLE=$(abspath $(PY)) \
	  -DBUILD_TESTING=OFF
	$(ROS_PREFIX) cmake --build $(MSGS_BUILD) -j 2 > $(MSGS_BUILD)/build.log 2>&1 \
	  || { tail -n 40 $(MSGS_BUILD)/build.log; exit 1; }
	cmake --install $(MSGS_BUILD) > /dev/null
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/mr-ident demo --out-dir out/demo

paper: $(STAMP)
	$(VENV)/bin/mr-ident paper --out-dir out/paper

# the whole suite (pytest-xdist): one worker per core for the computing tests and one more
# for the ROS group (nodes and programs in real time, mostly waiting; test/conftest.py),
# which one worker runs one test after another; then the tests marked realtime (timing
# claims), alone. TEST_ARGS narrows it, e.g. TEST_ARGS=test/test_lpm.py (pytest's exit
# code 5, nothing selected, is no failure of the second run)
TEST_WORKERS ?= $(shell echo $$(( $$(nproc) + 1 )))
test: $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadgroup --durations=15 -m "not realtime" $(TEST_ARGS)
	$(PY) -m pytest -q -m realtime $(or $(TEST_ARGS),test) || [ $$? = 5 ]

# the numerics part of the suite (-m "not ros": every test but the ROS group's, which need DDS
# or a browser) on one worker per core, under the BLAS kernels the CPU selects or those
# OPENBLAS_CORETYPE names (.ci/run: Haswell and Zen); the first line names the kernels
NUMERICS_WORKERS ?= $(shell nproc)
NUMERICS := -q -n $(NUMERICS_WORKERS) -m "not ros and not realtime"
test-numerics: $(STAMP)
	$(PY) scripts/blas_kernels.py
	$(PY) -m pytest $(NUMERICS) $(TEST_ARGS)

# the numerics part in .venv-apt: the versions a ROS 2 Jazzy robot has from Ubuntu 24.04's
# apt (numpy 1.26.4, scipy 1.11.4, matplotlib 3.6.3; requirements-apt.txt) and no ROS 2, so
# the package's ROS layer is not collected and tests needing ROS's interfaces skip
APT_VENV  := .venv-apt
APT_STAMP := $(APT_VENV)/.installed
$(APT_STAMP): requirements-apt.txt setup.py setup.cfg
	test -x $(APT_VENV)/bin/python || python3 -m venv $(APT_VENV)
	$(APT_VENV)/bin/python -m pip install --quiet --disable-pip-version-check -r requirements-apt.txt
	$(APT_VENV)/bin/python -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation --use-pep517 -e .
	touch $(APT_STAMP)

venv-apt: $(APT_STAMP)

test-apt: $(APT_STAMP)
	$(APT_VENV)/bin/python scripts/blas_kernels.py
	$(APT_VENV)/bin/python -m pytest $(NUMERICS) --ignore=mr_ident/ros $(TEST_ARGS)

# ruff (lint, format) and mypy (strict on numerics and I/O); .ci/run runs it before the tests
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy

# the documentation site (docs/, mkdocs.yml) into out/site; --strict: a broken link or anchor fails
docs: $(STAMP)
	$(VENV)/bin/mkdocs build --strict --site-dir out/site

# The workspace flow of a robot, with no flags (.ci/workspace): the tracked files as
# out/colcon_ws/src/mr_ident (`git add` new files first), catkin_pkg's crawl, rosdep install
# (simulated, against the rosdistro snapshot in test/data), colcon build, source
# install/setup.bash, the console scripts from the install space, colcon test of a fast
# subset (COLCON_TESTS, module names: the interfaces, the packaging checks, the imports, the
# node's lifecycle from the install space; the rest of the suite is make test's), colcon
# test-result. The
# underlay (out/underlay) is a venv of the ROS 2 wheels and the pinned requirements holding
# neither mr_ident nor mr_ident_msgs, as /opt/ros/jazzy would. .ci/run runs this target.
UNDERLAY       := out/underlay
UNDERLAY_STAMP := $(UNDERLAY)/.installed
COLCON_WS      := out/colcon_ws
COLCON_TESTS   := test_msgs|test_packaging|test_core_imports_no_ros|test_ros_lifecycle
$(UNDERLAY_STAMP): requirements.txt requirements-colcon.txt
	test -x $(UNDERLAY)/bin/python || python3 -m venv $(UNDERLAY)
	$(UNDERLAY)/bin/python -m pip install --quiet --disable-pip-version-check \
	  -r requirements.txt -r requirements-colcon.txt
	touch $(UNDERLAY_STAMP)

colcon: $(UNDERLAY_STAMP)
	.ci/workspace $(UNDERLAY) $(COLCON_WS) '^($(COLCON_TESTS))$$'

# The node's DDS tests with the numpy and scipy a Jazzy robot gets from apt (Ubuntu noble's
# python3-numpy 1.26.4 and python3-scipy 1.11.4, what rosdep installs for the package.xml
# keys), put ahead of .venv's newer ones on PYTHONPATH (the tests' programs inherit it).
# .ci/run runs this target.
APT_NUMPY := out/apt_numpy
APT_TESTS := test/test_ros_node.py test/test_ros_lifecycle.py test/test_ros_managed.py \
             test/test_ros_honest.py test/test_ros_record_keeps.py
test-apt-numpy: $(STAMP)
	test -d $(APT_NUMPY)/scipy || $(PY) -m pip install --quiet --disable-pip-version-check \
	  --no-deps --target $(APT_NUMPY) numpy==1.26.4 scipy==1.11.4
	PYTHONPATH=$(abspath $(APT_NUMPY)) $(PY) -c "import numpy, scipy; \
	  assert (numpy.__version__, scipy.__version__) == ('1.26.4', '1.11.4')"
	PYTHONPATH=$(abspath $(APT_NUMPY)) $(PY) -m pytest -q -p no:cacheprovider $(APT_TESTS)

bench: $(STAMP)
	$(PY) benchmarks/bench_identify.py

# docs/lrm.png: polynomial and rational local models on a lightly damped mode (a few seconds)
lrm-figure: $(STAMP)
	$(PY) scripts/lrm_figure.py

# accuracy of every LPM method at n = 8 and n = auto: paper's loop (3 seeds), 24 random
# loops, the reported std over 50 runs; about 2.5 min on 2 cores
bench-structured: $(STAMP)
	$(PY) benchmarks/bench_structured.py

# fit_frf on drawn modal plants (order 2-30, SISO and 3x3): pole errors against the
# Cramér-Rao bound, the cost in its band (with its 95 % interval: 100 plants x 2 noise
# draws per shape), stability, the order found (8 plants), time per fit; scikit-rf's
# VectorFitting beside it on the same data; 1e5 bins, 3x3, order 40 timed. About 10 min.
bench-fit: $(STAMP)
	$(PY) benchmarks/bench_fit.py

# missing samples as unknowns: the paper's loop, 1 % and 5 % dropped in bursts of up to 5,
# against none dropped and linear interpolation; 50 seeded runs, a few minutes on 2 cores
bench-missing: $(STAMP)
	$(PY) benchmarks/bench_missing.py

# noise-free accuracy of the PFG from data and of P_h from a low-rate y per decade of the
# alias range, three local models, ten random loops; about 2.5 min on 2 cores
bench-alias-range: $(STAMP)
	$(PY) benchmarks/bench_alias_range.py

# r at the setpoint against r at the plant input (equal rms of u), Welch's indirect estimate
# beside it, std honesty over 50 runs of the paper's loop, 600 s; a few minutes on 2 cores
bench-setpoint: $(STAMP)
	$(PY) benchmarks/bench_setpoint.py

clean:
	rm -rf out .pytest_cache

bench-bag: $(STAMP)
	$(PY) benchmarks/bench_bag.py

bench-live: $(STAMP)
	$(PY) benchmarks/bench_live.py

# diagnose on seeded random loops (100 per cause, 100 pairs, 100 with nothing hidden);
# 1200 cases, about 45 min on 2 cores (more when shared with other work), in three parts,
# each its own JSON in out/bench_diagnose/: `make bench-diagnose PART=A` (nothing hidden and the first
# five causes), PART=B (the other five), PART=C (the pairs), PART=D (beyond the vocabulary:
# nonlinear actuators and unlisted effects, benchmarks/bench_diagnose_beyond.py, its own
# beyond.json and beyond.md; BEYOND= passes options, e.g. BEYOND="--per-cell 1 --per-effect 3");
# without PART all four, then the merged report of A-C and D's. Not part of `make test`
BENCH_DIAG := $(PY) benchmarks/bench_diagnose.py
DIAG_OUT   := out/bench_diagnose
DIAG_A     := --causes gain_error,input_delay,additive_mode,mode_shift,series_lowpass --pairs 0
DIAG_B     := --causes series_resonance,controller_notch,control_delay,sampling_offset,periodic_disturbance --pairs 0 --none 0
DIAG_C     := --per-cause 0 --none 0
PART       ?= A B C D
BEYOND     ?=
bench-diagnose: $(STAMP)
	mkdir -p $(DIAG_OUT)
	for p in $(PART); do \
	  case $$p in A) a="$(DIAG_A)";; B) a="$(DIAG_B)";; C) a="$(DIAG_C)";; \
	    D) $(PY) benchmarks/bench_diagnose_beyond.py $(BEYOND) --json $(DIAG_OUT)/beyond.json \
	         > $(DIAG_OUT)/beyond.md || exit 1; continue;; \
	    *) echo "error: PART must be A, B, C or D, got $$p" >&2; exit 2;; esac; \
	  $(BENCH_DIAG) $$a --json $(DIAG_OUT)/part$$p.json > $(DIAG_OUT)/part$$p.md || exit 1; \
	done
	if ls $(DIAG_OUT)/part*.json >/dev/null 2>&1; then $(BENCH_DIAG) --report $(DIAG_OUT)/part*.json; fi
	if [ -f $(DIAG_OUT)/beyond.md ]; then cat $(DIAG_OUT)/beyond.md; fi

# false alarms of the plant monitoring: 5 loops x 600 s watched against their own model (~1 min)
bench-monitor: $(STAMP)
	$(PY) benchmarks/bench_monitor.py

# 30 min of sim + node + recorder (SOAK_MINUTES=5 make soak for a shorter run); ~4 GB in out/soak
soak: $(STAMP)
	$(PY) benchmarks/soak.py

motor-bench: $(STAMP)
	$(PY) scripts/motor_bench.py
