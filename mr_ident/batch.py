# SPDX-License-Identifier: Apache-2.0
"""``mr-ident batch``: identify or diagnose many recordings, one summary table.

Every recording is one job, run in a worker process (a local process pool by default, or
the workers of an existing Dask cluster through its ``concurrent.futures`` executor). A
job reads its recording, writes its own result file (``<name>.npz`` for identify, the
diagnose report ``<name>.json`` for diagnose) and returns one row of the table: the
window used, P_h and its standard deviation at the chosen frequencies, the drift against
a reference estimate or the model, for identify the PFG from data there, and for
diagnose the cause. A job that fails returns a
row with its error; the batch goes on.

Memory: a pool worker serves one recording and is then replaced (``max_tasks_per_child``),
so a worker's memory is that of one recording, returned to the system after it; each job
runs identify on ``threads`` threads so that the workers do not oversubscribe the CPUs.
"""

from __future__ import annotations

import csv
import glob
import io
import math
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .errors import ConfigError, MrIdentError
from .live.recordings import BAG_SUFFIXES, DATA_SUFFIXES, is_bag
from .live.spans import DEFAULT_SPAN, check_span

if TYPE_CHECKING:
    from .app.requests import Notice, Reading
    from .numerics.results import FRF
    from .numerics.systems.model import Model

TASKS = ("identify", "diagnose")


@dataclass(frozen=True)
class BatchOptions:
    """What every job of a batch does (picklable: it travels to the workers).

    ``frequencies`` (Hz) are where the table reports P_h; ``reference`` (an FRF, shape
    (K, n_y, n_u)) or else ``model`` is what the drift is measured against.
    """

    task: str
    out_dir: str
    frequencies: tuple[float, ...]
    model: Model | None = None
    reference: FRF | None = None
    specs: dict[str, list[str]] | None = None
    topics: tuple[str, ...] | None = None
    fs_high: float | None = None
    ratio: int | None = None
    method: str = "freq-lifted"
    n: int | str | None = "auto"
    degree: int = 2
    local: str = "polynomial"
    period: int | None = None
    span: str = DEFAULT_SPAN
    msg_path: tuple[Path, ...] = ()
    threads: int = 1
    injection: str | None = None

    def __post_init__(self) -> None:
        check_span(self.span)
        if self.task not in TASKS:
            raise ConfigError(f"task must be one of {', '.join(TASKS)}, got {self.task!r}")
        if self.task == "diagnose" and self.model is None:
            raise ConfigError("diagnose needs a model: pass --model")
        if not self.frequencies or not all(math.isfinite(f) and f > 0 for f in self.frequencies):
            raise ConfigError(f"--at must list positive frequencies in Hz, got {self.frequencies}")


@dataclass(frozen=True)
class Job:
    """One recording and the file its result goes to."""

    recording: str
    result: str


@dataclass
class BatchResult:
    """The table's columns and rows (recordings in the order given) and the failures."""

    columns: list[str]
    rows: list[dict[str, str]] = field(default_factory=list)

    @property
    def failed(self) -> int:
        """Rows whose recording failed."""
        return sum(r["status"] != "ok" for r in self.rows)


def find_recordings(inputs: Sequence[str]) -> list[Path]:
    """Recordings named by ``inputs``, sorted per input, without duplicates.

    Files, rosbag2 directories, directories of recordings (not recursive), glob patterns.

    ConfigError when an input matches nothing.
    """
    found: list[Path] = []
    for text in inputs:
        matches = (
            [Path(m) for m in sorted(glob.glob(text))] if glob.has_magic(text) else [Path(text)]
        )
        hits: list[Path] = []
        for p in matches:
            if p.is_dir() and not (p / "metadata.yaml").exists():
                hits += sorted(
                    c
                    for c in p.iterdir()
                    if (c / "metadata.yaml").exists()
                    or (c.is_file() and c.suffix.lower() in DATA_SUFFIXES + BAG_SUFFIXES)
                )
            elif p.exists():
                hits.append(p)
        if not hits:
            raise ConfigError(
                f"no recording found for {text!r} (expected a .csv, .npz or .mcap file, a "
                "rosbag2 directory, a directory holding them, or a glob pattern)"
            )
        found += [h for h in hits if h not in found]
    return found


def plan(recordings: Sequence[Path], out_dir: Path, task: str) -> list[Job]:
    """A job per recording; result names from the recordings' names, made unique."""
    suffix = ".npz" if task == "identify" else ".json"
    used: set[str] = set()
    jobs = []
    for rec in recordings:
        stem = rec.name if rec.is_dir() else rec.stem
        name, k = stem, 1
        while name in used:
            k += 1
            name = f"{stem}-{k}"
        used.add(name)
        jobs.append(Job(str(rec), str(out_dir / f"{name}{suffix}")))
    return jobs


def _fmt(v: float) -> str:
    return "" if v is None or not math.isfinite(v) else f"{v:.6g}"


def _entry(o: int, i: int, n_y: int, n_u: int) -> str:
    """The entry part of a column name: empty for SISO, ``[o,i]`` for MIMO."""
    return "" if n_y * n_u == 1 else f"[{o},{i}]"


def columns(opts: BatchOptions, n_y: int = 1, n_u: int = 1) -> list[str]:
    """The table's columns (entries ``[o,i]`` appear for MIMO data only)."""
    cols = ["recording", "status", "error", "notes", "first", "n_samples", "duration_s"]
    cols += ["fs_high", "ratio", "method", "result"]
    for f in opts.frequencies:
        for o in range(n_y):
            for i in range(n_u):
                e = _entry(o, i, n_y, n_u)
                cols += [f"mag{e}@{f:g}Hz", f"phase_deg{e}@{f:g}Hz", f"std{e}@{f:g}Hz"]
                if opts.reference is not None or opts.model is not None:
                    cols.append(f"drift{e}@{f:g}Hz")
    if opts.reference is not None or opts.model is not None:
        cols.append("drift_max")
    if opts.task == "identify":
        for f in opts.frequencies:
            cols += [f"pfg_data@{f:g}Hz", f"pfg_data_std@{f:g}Hz"]
    if opts.task == "diagnose":
        cols += ["cause", "parameters", "fit_y_before", "fit_y_after"]
    return cols


def _at(frequency: np.ndarray, values: np.ndarray, f: float) -> Any:
    """``values`` at the bin nearest to ``f``."""
    return values[int(np.argmin(np.abs(frequency - f)))]


def _frf_columns(
    opts: BatchOptions, frequency: np.ndarray, P: np.ndarray, P_std: np.ndarray
) -> dict[str, str]:
    row: dict[str, str] = {}
    n_y, n_u = P.shape[1:]
    ref = None
    if opts.reference is not None:
        ref = np.array(
            [_at(opts.reference.frequency, opts.reference.response, f) for f in opts.frequencies]
        )
    elif opts.model is not None:
        bins = np.array([_at(frequency, frequency, f) for f in opts.frequencies])
        ref = opts.model.plant_discrete().freqresp(bins)
    if ref is not None and ref.shape[1:] != P.shape[1:]:
        raise ConfigError(
            f"the reference is {ref.shape[1]}x{ref.shape[2]} (n_y x n_u) but the recording "
            f"gives {n_y}x{n_u}"
        )
    drifts = []
    for k, f in enumerate(opts.frequencies):
        p, s = _at(frequency, P, f), _at(frequency, P_std, f)
        for o in range(n_y):
            for i in range(n_u):
                e = _entry(o, i, n_y, n_u)
                row[f"mag{e}@{f:g}Hz"] = _fmt(abs(p[o, i]))
                row[f"phase_deg{e}@{f:g}Hz"] = _fmt(float(np.degrees(np.angle(p[o, i]))))
                row[f"std{e}@{f:g}Hz"] = _fmt(float(s[o, i]))
                if ref is not None:
                    d = float(abs(p[o, i] - ref[k, o, i]) / abs(ref[k, o, i]))
                    drifts.append(d)
                    row[f"drift{e}@{f:g}Hz"] = _fmt(d)
    if ref is not None:
        row["drift_max"] = _fmt(max(drifts))
    return row


def run_job(job: Job, opts: BatchOptions) -> dict[str, str]:
    """One recording: read, identify or diagnose, write its result; the table row.

    Never raises for a bad recording: the row's ``status`` is ``error`` and ``error`` says
    why (the message a single ``mr-ident identify`` would print).
    """
    row = {"recording": job.recording, "status": "ok", "error": "", "result": ""}
    try:
        row.update(_run(job, opts))
    except MrIdentError as err:
        from .cli.common import told  # a request's fields as the command line's flags

        row.update(status="error", error=told(err))
    except OSError as err:
        row.update(status="error", error=f"{err.filename or ''}: {err.strerror or err}")
    except Exception as err:  # a bug or a library failure: still one row, not the batch
        row.update(status="error", error=f"{type(err).__name__}: {err}")
    return row


def _run(job: Job, opts: BatchOptions) -> dict[str, str]:
    """One job through the application (:mod:`mr_ident.app`): its result written, its row."""
    from .app.requests import Reading

    path = Path(job.recording)
    bag = is_bag(path)  # the sources apply to the bags of a batch, data files give r, u, y
    reading = Reading(
        path, opts.specs if bag else None, opts.topics, opts.span, tuple(opts.msg_path)
    )
    if opts.task == "identify":
        return _identify(job, opts, reading)
    return _diagnose(job, opts, reading)


def _row(job: Job, opts: BatchOptions, first: int, N: int, fs: float, F: int) -> dict[str, str]:
    """The columns every task fills: the record read and its rates."""
    return {
        "first": str(first),
        "n_samples": str(N),
        "duration_s": _fmt(N / fs),
        "fs_high": _fmt(fs),
        "ratio": str(F),
        "method": opts.method,
        "result": job.result,
    }


def _warnings(notices: Iterable[Notice]) -> str:
    """What the reading noticed, for the table's ``notes`` column (fields said as flags)."""
    from .cli.common import flag

    return " | ".join(n.told(flag) for n in notices if n.kind == "warning")


def _identify(job: Job, opts: BatchOptions, reading: Reading) -> dict[str, str]:
    from .app.identify import Identified, identify_recording
    from .app.requests import IdentifyRequest
    from .io.datafile import write_result

    req = IdentifyRequest(
        reading,
        opts.model,
        fs_high=opts.fs_high,
        ratio=opts.ratio,
        method=opts.method,
        n=opts.n,
        degree=opts.degree,
        local=opts.local,
        workers=opts.threads,
        injection=opts.injection,
    )
    got = identify_recording(req)
    assert isinstance(got, Identified)  # no period: no BLA
    ident = got.identification
    write_result(job.result, ident, got.structure)
    row = _row(job, opts, got.first, got.n_samples, got.fs_high, got.ratio)
    row["notes"] = _warnings(got.notices)
    pl, pd = ident.plant, ident.pfg_data
    row.update(_frf_columns(opts, pl.frequency, pl.response, pl.std))
    if pd is not None:  # the PFG from data alone, no controller needed
        for f in opts.frequencies:
            row[f"pfg_data@{f:g}Hz"] = _fmt(float(_at(pd.frequency, pd.gain, f)))
            row[f"pfg_data_std@{f:g}Hz"] = _fmt(float(_at(pd.frequency, pd.std, f)))
    return row


def _diagnose(job: Job, opts: BatchOptions, reading: Reading) -> dict[str, str]:
    import json

    from .app.diagnose import diagnose_recording
    from .app.requests import DiagnoseRequest
    from .diagnosis.report import report_dict
    from .io.atomic import atomic_write

    assert opts.model is not None  # checked by BatchOptions
    req = DiagnoseRequest(
        reading,
        opts.model,
        period=opts.period,
        n=opts.n,
        degree=opts.degree,
        fs_high=opts.fs_high,
        ratio=opts.ratio,
        rates="agree",
        names=(job.recording, ""),
        injection=opts.injection,
    )
    got = diagnose_recording(req)
    d, data = got.diagnosis, got.data
    summary = report_dict(d, extended_model=None, alpha=0.01)
    atomic_write(job.result, lambda fh: json.dump(summary, fh, indent=2), binary=False)
    fs, F = data.rates()
    row = _row(job, opts, data.first, data.n_samples, fs, F)
    row["notes"] = _warnings(got.notices)
    ev = d.evidence_before
    row.update(_frf_columns(opts, ev.frequency, ev.P_hat, ev.P_std))
    row.update(
        cause=d.cause,
        parameters="; ".join(f"{k}={v:.6g}" for k, v in d.parameters.items()),
        fit_y_before=_fmt(d.fit_before.y),
        fit_y_after=_fmt(d.fit_after.y),
    )
    return row


def local_pool(workers: int) -> ProcessPoolExecutor:
    """The embedded executor: ``workers`` processes, each replaced after one recording."""
    return ProcessPoolExecutor(
        max_workers=workers, mp_context=get_context("spawn"), max_tasks_per_child=1
    )


def run_batch(
    jobs: Sequence[Job],
    opts: BatchOptions,
    executor: Executor,
    progress: Callable[[int, int, dict[str, str]], None] | None = None,
) -> BatchResult:
    """Run every job on ``executor``.

    Rows come in the order of ``jobs`` whatever the order of completion. A job whose worker
    died (killed, out of memory) is an error row too.
    """
    futures: dict[Future[dict[str, str]], int] = {
        executor.submit(run_job, job, opts): k for k, job in enumerate(jobs)
    }
    rows: list[dict[str, str] | None] = [None] * len(jobs)
    for done, fut in enumerate(as_completed(futures), 1):
        k = futures[fut]
        try:
            row = fut.result()
        except Exception as err:  # the worker itself failed, not the recording
            row = {
                "recording": jobs[k].recording,
                "status": "error",
                "error": f"worker failed: {type(err).__name__}: {err}",
            }
        rows[k] = row
        if progress is not None:
            progress(done, len(jobs), row)
    n_y, n_u = _entries([r for r in rows if r is not None])
    cols = columns(opts, n_y, n_u)
    return BatchResult(cols, [{c: r.get(c, "") for c in cols} for r in rows if r is not None])


def _entries(rows: Iterable[dict[str, str]]) -> tuple[int, int]:
    """(n_y, n_u) of the results, from the entry columns the rows carry."""
    best = (1, 1)
    for r in rows:
        for key in r:
            if key.startswith("mag[") and "]" in key:
                o, i = (int(x) for x in key[4 : key.index("]")].split(","))
                best = (max(best[0], o + 1), max(best[1], i + 1))
    return best


def write_table(result: BatchResult, path: str | Path) -> None:
    """The summary table as CSV (one row per recording, written whole or not at all)."""
    from .io.atomic import atomic_write

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=result.columns, lineterminator="\n")
    w.writeheader()
    w.writerows(result.rows)
    atomic_write(Path(path), lambda fh: fh.write(buf.getvalue()), binary=False)


def default_workers(n_jobs: int) -> int:
    """Worker processes by default: one per CPU this process may use, at most one per job."""
    from .numerics.threads import resolve_workers

    return max(1, min(resolve_workers(None), n_jobs))


def threads_per_job(workers: int) -> int:
    """Identification threads of each of ``workers`` processes: the CPUs shared out."""
    from .numerics.threads import resolve_workers

    return max(1, resolve_workers(None) // workers)


def dask_client(address: str) -> Any:
    """A client of the Dask cluster at ``address``; its ``get_executor()`` runs the jobs.

    ConfigError when the optional extra is not installed or the scheduler does not answer.
    """
    try:
        from distributed import Client
    except ImportError:
        raise ConfigError(
            "--scheduler needs Dask distributed, the optional extra: "
            "pip install 'mr_ident[cluster]'"
        ) from None
    try:
        return Client(address, timeout=10)
    except (OSError, TimeoutError) as err:
        raise ConfigError(f"--scheduler {address}: no Dask scheduler answered ({err})") from None


def summary_text(result: BatchResult, width: int = 100) -> str:
    """A short table for the terminal: recording, status, drift and cause or error."""
    lines = [f"{'recording':<40} {'status':<6} {'drift_max':>9}  cause / error"]
    for r in result.rows:
        what = r.get("cause", "") if r["status"] == "ok" else r["error"]
        name = Path(r["recording"]).name[:40]
        line = f"{name:<40} {r['status']:<6} {r.get('drift_max', ''):>9}  {what}"
        lines.append(line[:width])
    return "\n".join(lines)
