# SPDX-License-Identifier: Apache-2.0
"""What ROS tools read: every package.xml dependency resolves with rosdep on Jazzy, what has
no key is said to come from pip, and the license is there as declared.

The keys are checked against a snapshot of the rosdistro repository in test/data/rosdistro
(rosdep/base.yaml, rosdep/python.yaml, jazzy/distribution.yaml; see its SOURCE.md).
"""

from __future__ import annotations

import ast
import os
import re
import subprocess
import xml.etree.ElementTree as ET
from functools import cache
from importlib.util import find_spec
from pathlib import Path

import pytest
import yaml
from conftest import ROOT, console_script

ROSDISTRO = ROOT / "test" / "data" / "rosdistro"
PACKAGES = {"mr_ident": ROOT, "mr_ident_msgs": ROOT / "mr_ident_msgs"}
# Jazzy's Tier 1 platform: a key must resolve there
OS_NAME, OS_VERSION = "ubuntu", "noble"
DEPEND_TAGS = (
    "depend",
    "build_depend",
    "build_export_depend",
    "buildtool_depend",
    "buildtool_export_depend",
    "exec_depend",
    "test_depend",
    "doc_depend",
)
# setup.py's install_requires that a declared rosdep key provides (the rest are pip-only)
PIP_BY_KEY = {
    "numpy": "python3-numpy",
    "scipy": "python3-scipy",
    "PyYAML": "python3-yaml",
    "matplotlib": "python3-matplotlib",
    "setuptools": "python3-setuptools",
    "mcap-ros2-support": "mcap-ros2-support",
}


def _load(path: Path):
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    with path.open() as fh:
        return yaml.load(fh, Loader=loader)


@cache
def rosdep_rules() -> dict:
    rules: dict = {}
    for name in ("base.yaml", "python.yaml"):
        rules.update(_load(ROSDISTRO / "rosdep" / name))
    return rules


@cache
def jazzy_packages() -> frozenset[str]:
    names: set[str] = set()
    for repo, entry in _load(ROSDISTRO / "jazzy" / "distribution.yaml")["repositories"].items():
        release = entry.get("release")
        if release:
            names.update(release.get("packages", [repo]))
    return frozenset(names)


def resolves(rule, os_name: str = OS_NAME, version: str = OS_VERSION) -> bool:
    """Whether a rosdep rule installs something (or nothing, on purpose) on that platform."""
    if not isinstance(rule, dict):
        return False
    entry = rule.get(os_name, rule.get("*"))
    if isinstance(entry, dict) and not {"apt", "pip", "source"} & entry.keys():
        entry = entry.get(version, entry.get("*"))  # per release of the OS
    return entry is not None


def pip_keys() -> dict[str, list[str]]:
    """The rosdep keys that install a pip package on the platform, by package name."""
    keys: dict[str, list[str]] = {}
    for key, rule in rosdep_rules().items():
        entry = rule.get(OS_NAME, rule.get("*")) if isinstance(rule, dict) else None
        pip = entry.get("pip") if isinstance(entry, dict) else None
        names = pip.get("packages", []) if isinstance(pip, dict) else pip
        for name in names if isinstance(names, list) else []:
            keys.setdefault(name.lower(), []).append(key)
    return keys


def dependencies(package: str) -> list[tuple[str, str]]:
    """(tag, key) of every dependency in a package.xml."""
    root = ET.parse(PACKAGES[package] / "package.xml").getroot()
    return [(tag, e.text.strip()) for tag in DEPEND_TAGS for e in root.findall(tag)]


def pip_only(package: str) -> set[str]:
    """The names of the package.xml comment line ``pip-only: a, b, c``."""
    text = (PACKAGES[package] / "package.xml").read_text()
    lines = re.findall(r"^\s*pip-only:(.*)$", text, flags=re.MULTILINE)
    return {n.strip() for line in lines for n in line.split(",") if n.strip()}


def setup_keyword(name: str):
    """The literal value of a keyword argument of setup.py's setup() (nothing run)."""
    for node in ast.walk(ast.parse((ROOT / "setup.py").read_text())):
        if isinstance(node, ast.keyword) and node.arg == name:
            return ast.literal_eval(node.value)
    raise AssertionError(f"setup.py has no {name}")


def install_requires() -> list[str]:
    return [re.split(r"[<>=!~\[ ;]", r)[0] for r in setup_keyword("install_requires")]


@pytest.fixture(scope="module", autouse=True)
def _snapshot():
    if not ROSDISTRO.is_dir():
        pytest.fail(f"the rosdistro snapshot {ROSDISTRO} is missing (see its SOURCE.md)")


@pytest.mark.parametrize("package", sorted(PACKAGES))
def test_every_dependency_is_a_jazzy_package_or_a_rosdep_key_that_resolves(package):
    rules, jazzy = rosdep_rules(), jazzy_packages()
    bad = [
        f"<{tag}>{key}</{tag}>"
        for tag, key in dependencies(package)
        if key not in jazzy and not resolves(rules.get(key))
    ]
    assert not bad, (
        f"{package}/package.xml: {bad} are neither Jazzy packages nor rosdep keys that "
        f"resolve on {OS_NAME} {OS_VERSION}; declare the pip-only ones in the "
        "'pip-only:' comment instead"
    )


def test_a_workspace_crawl_finds_the_root_package_alone_and_it_declares_the_interfaces_needs():
    """colcon and rosdep (catkin_pkg) stop crawling at the root's package.xml: in a workspace
    the root package is all they see, so it builds the interfaces (CMakeLists.txt) and
    declares everything mr_ident_msgs/package.xml asks for."""
    packages = pytest.importorskip("catkin_pkg.packages")
    found = {path: pkg.name for path, pkg in packages.find_packages(str(ROOT)).items()}
    assert found == {".": "mr_ident"}, found
    root = ET.parse(ROOT / "package.xml").getroot()
    assert root.findtext("export/build_type") == "ament_cmake"
    declared = {key for _, key in dependencies("mr_ident")}
    needed = {key for _, key in dependencies("mr_ident_msgs")}
    assert needed <= declared, f"package.xml lacks {sorted(needed - declared)}"
    assert "mr_ident_msgs" not in declared  # no package of that name in a workspace
    cmake = (ROOT / "CMakeLists.txt").read_text()
    assert re.search(r"ExternalProject_Add\(mr_ident_msgs\s", cmake)


def test_colcon_installs_the_console_scripts_setup_py_names():
    """CMakeLists.txt writes the scripts of a colcon build; setup.py's entry_points, pip's."""
    cmake = (ROOT / "CMakeLists.txt").read_text()
    block = re.search(r"set\(MR_IDENT_CONSOLE_SCRIPTS(.*?)\)", cmake, flags=re.DOTALL)
    assert block is not None
    listed = re.findall(r'"([^"]+)"', block.group(1))
    want = [e.replace(" ", "") for e in setup_keyword("entry_points")["console_scripts"]]
    assert listed == want


def test_the_resolver_knows_a_key_from_a_name():
    rules = rosdep_rules()
    assert resolves(rules["python3-numpy"]) and resolves(rules["mcap-ros2-support"])
    for missing in ("python3-threadpoolctl", "python3-plotly"):
        assert not resolves(rules.get(missing))
    assert not resolves({"ubuntu": {"focal": ["x"]}})
    assert not resolves({"ubuntu": {"noble": None, "*": ["x"]}})
    assert resolves({"*": {"pip": {"packages": ["x"]}}})
    assert {"rclpy", "std_srvs", "rosidl_default_generators"} <= jazzy_packages()
    assert "python3-rosbags-pip" in pip_keys()["rosbags"]


def pinned(name: str) -> dict[str, str]:
    """The ``package==version`` lines of the requirements file ``name``, by normalized name."""
    lines = (line.split("#")[0].strip() for line in (ROOT / name).read_text().splitlines())
    pairs = (line.split("==") for line in lines if "==" in line)
    return {re.sub(r"[-_.]+", "-", n.split("[")[0]).lower(): v.strip() for n, v in pairs}


def test_both_tested_sets_of_versions_lie_in_the_range_setup_py_states():
    """requirements.txt (the newest tested) and requirements-apt.txt (what Ubuntu 24.04's apt
    gives a Jazzy robot, tested by make test-apt) pin every runtime requirement within it."""
    from packaging.requirements import Requirement

    for file in ("requirements.txt", "requirements-apt.txt"):
        pins = pinned(file)
        for text in setup_keyword("install_requires"):
            req = Requirement(text)
            version = pins.get(re.sub(r"[-_.]+", "-", req.name).lower())
            assert version is not None, f"{file} pins no {req.name}"
            assert req.specifier.contains(version), f"{file}: {req.name} {version} not in {req}"
    apt = pinned("requirements-apt.txt")
    assert (apt["numpy"], apt["scipy"], apt["matplotlib"]) == ("1.26.4", "1.11.4", "3.6.3")


def test_every_runtime_requirement_is_declared_or_said_to_come_from_pip():
    declared = {key for _, key in dependencies("mr_ident")}
    pip = pip_only("mr_ident")
    rules = rosdep_rules()
    for name in install_requires():
        if name in pip:
            assert name not in PIP_BY_KEY, f"{name} has a rosdep key: declare it instead"
            continue
        assert name in PIP_BY_KEY, (
            f"setup.py requires {name}: declare its rosdep key in package.xml or name it "
            "in the package.xml comment 'pip-only: ...'"
        )
        assert PIP_BY_KEY[name] in declared, f"package.xml lacks {PIP_BY_KEY[name]} ({name})"
    by_pip = pip_keys()
    for name in pip:
        keys = [k for k in (f"python3-{name.lower()}",) if resolves(rules.get(k))]
        keys += by_pip.get(name.lower(), [])
        assert not keys, f"{name} is said to be pip-only, but rosdep has {keys} for it now"


def test_the_interface_package_declares_what_rosidl_needs():
    deps = dependencies("mr_ident_msgs")
    assert ("buildtool_depend", "rosidl_default_generators") in deps
    assert ("exec_depend", "rosidl_default_runtime") in deps
    root = ET.parse(PACKAGES["mr_ident_msgs"] / "package.xml").getroot()
    assert root.findtext("member_of_group") == "rosidl_interface_packages"
    assert root.findtext("export/build_type") == "ament_cmake"
    assert root.get("format") == "3"


@pytest.mark.parametrize("package", sorted(PACKAGES))
def test_the_license_is_apache_2_as_declared(package):
    root = ET.parse(PACKAGES[package] / "package.xml").getroot()
    assert root.findtext("license") == "Apache-2.0"
    text = (PACKAGES[package] / "LICENSE").read_text()
    assert text.lstrip().startswith("Apache License")
    assert "Version 2.0, January 2004" in text
    assert "END OF TERMS AND CONDITIONS" in text


def test_the_console_scripts_are_found_where_they_are_installed_and_start():
    """In a venv (make) beside the interpreter, in a colcon workspace under lib/mr_ident."""
    names = [e.split("=")[0].strip() for e in setup_keyword("entry_points")["console_scripts"]]
    assert names == ["mr-ident", "mr-ident-node", "mr-ident-sim"]
    for name in names:
        assert os.access(console_script(name), os.X_OK)
    # the node has no --help (test_ros_record runs it); the sim starts where ROS 2 is installed
    started = ["mr-ident", *(["mr-ident-sim"] if find_spec("rclpy") else [])]
    for name in started:
        out = subprocess.run(
            [console_script(name), "--help"], capture_output=True, text=True, timeout=60
        )
        assert out.returncode == 0 and out.stdout.startswith(f"usage: {name}"), out.stderr


def test_every_source_file_says_its_license():
    """An SPDX line (REP 2004's quality level asks for a license per file) at the top of every
    tracked Python, JavaScript, HTML and CMake file: ``Apache-2.0``, as declared."""
    listed = subprocess.run(
        ["git", "ls-files", "*.py", "*.js", "*.html", "CMakeLists.txt", "**/CMakeLists.txt"],
        cwd=ROOT, capture_output=True, text=True, check=False,
    )  # fmt: skip
    if listed.returncode != 0 or not listed.stdout.strip():
        pytest.skip("not a git checkout (an installed or copied tree): nothing to list")
    missing = [
        f
        for f in listed.stdout.split()
        if "SPDX-License-Identifier: Apache-2.0" not in "".join((ROOT / f).open().readlines()[:3])
    ]
    assert not missing, missing
