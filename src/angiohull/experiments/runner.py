"""Run an experiment's cases on local worker processes or a Dask cluster, resumably.

A run directory holds:

=================  ===============================================================================
``config.yaml``    the resolved configuration (after ``--quick``); a later run in the same folder
                   must resolve to the same one, else it stops before any work
``cases.jsonl``    one JSON record per case: every parameter :func:`~.cases.run_case` receives
``rows.csv``       the journal: one row per finished case, in the order they finished, appended
                   and fsync'ed one by one, never rewritten (:class:`~.rows.RowsJournal`)
``results.csv``    the rows sorted by ``case_id``, rewritten atomically at the end of every run
                   (also after an interruption)
``run.json``       package version, configuration digest, counts per status, and one entry per
                   invocation (start, wall time, cases run, workers or scheduler, interrupted)
=================  ===============================================================================

Running the same command again resumes: cases whose ``case_id`` is in ``rows.csv`` are skipped. An
interrupted run loses at most the cases that were in flight.
"""

from __future__ import annotations

import hashlib
import json
import math
import multiprocessing
import os
import platform
import signal
import sys
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterator, Optional, Sequence, TextIO

import numpy as np
import yaml

from .. import __version__
from .._yaml import read_yaml_file
from ..errors import AngiohullError
from .cases import STATUSES, expand_cases, row_columns, run_case
from .config import ConfigError, ExperimentConfig, config_from_dict, config_to_dict
from .rows import RowsJournal, read_rows, rows_to_csv, write_atomic

__all__ = ["RunSummary", "run_experiment", "prepare_run_dir", "default_workers", "load_run", "RunData",
           "CONFIG_FILE", "CASES_FILE", "ROWS_FILE", "RESULTS_FILE", "RUN_FILE"]

CONFIG_FILE, CASES_FILE, ROWS_FILE, RESULTS_FILE, RUN_FILE = "config.yaml", "cases.jsonl", "rows.csv", "results.csv", "run.json"

DASK_CONNECT_TIMEOUT_S = 20.0
"""How long to wait for a Dask scheduler to answer before giving up."""


def default_workers() -> int:
    """The CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@dataclass
class RunSummary:
    """What one invocation of :func:`run_experiment` did."""

    name: str
    run_dir: Path
    total: int  # cases of the experiment
    done_before: int  # finished before this invocation (resumed)
    done_now: int  # finished by this invocation
    status_counts: dict[str, int] = field(default_factory=dict)  # over every finished case
    wall_s: float = 0.0  # this invocation
    interrupted: bool = False
    executor: str = ""

    @property
    def done(self) -> int:
        return self.done_before + self.done_now

    @property
    def failures(self) -> int:
        return self.status_counts.get("failed", 0) + self.status_counts.get("error", 0)

    def text(self) -> str:
        state = "interrupted" if self.interrupted else ("complete" if self.done == self.total else "incomplete")
        counts = ", ".join(f"{n} {s}" for s, n in self.status_counts.items() if n)
        return (f"{self.name}: {state}, {self.done}/{self.total} cases ({self.done_before} resumed, {self.done_now} run "
                f"now{'' if not self.executor else ' on ' + self.executor}); {counts or 'no rows'}; wall time "
                f"{_duration(self.wall_s)}; rows: {self.run_dir / ROWS_FILE}; results: {self.run_dir / RESULTS_FILE}")


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"


class _Progress:
    """``name: done/total cases, rate, ETA`` on a stream (one rewritten line on a terminal)."""

    def __init__(self, name: str, total: int, done_before: int, stream: Optional[TextIO]):
        self.name, self.total, self.done_before = name, total, done_before
        self.stream = stream
        self.tty = bool(stream is not None and getattr(stream, "isatty", lambda: False)())
        self.interval = 0.5 if self.tty else 10.0
        self.start = time.perf_counter()
        self.last = -math.inf
        self.now = 0
        self.failed = 0

    def update(self, row: dict[str, Any]) -> None:
        self.now += 1
        self.failed += row["status"] in ("failed", "error")
        if time.perf_counter() - self.last >= self.interval:
            self.show()

    def line(self) -> str:
        elapsed = time.perf_counter() - self.start
        done = self.done_before + self.now
        rate = self.now / elapsed if elapsed > 0 and self.now else 0.0
        eta = (self.total - done) / rate if rate > 0 else math.inf
        percent = 100.0 * done / self.total if self.total else 100.0
        return (f"{self.name}: {done}/{self.total} cases ({percent:.0f} %), {rate:.2f} cases/s, "
                f"ETA {_duration(eta) if done < self.total else '0 s'}, {self.failed} failed")

    def show(self, final: bool = False) -> None:
        self.last = time.perf_counter()
        if self.stream is None:
            return
        if self.tty:
            end = "\n" if final else ""
            print("\r" + self.line().ljust(100), end=end, file=self.stream, flush=True)
        else:
            print(self.line(), file=self.stream, flush=True)


# -- the run directory ------------------------------------------------------------------------------
def _canonical(config: ExperimentConfig) -> str:
    return json.dumps(config_to_dict(config), sort_keys=True, separators=(",", ":"))


def _differences(old: Any, new: Any, where: str = "") -> list[str]:
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for key in sorted(set(old) | set(new), key=str):
            out += _differences(old.get(key), new.get(key), f"{where}.{key}" if where else str(key))
        return out
    return [] if old == new else [f"{where}: {old!r} there, {new!r} now"]


def prepare_run_dir(config: ExperimentConfig, run_dir: str | Path) -> Path:
    """Create the run directory with ``config.yaml``, or check that it holds this configuration."""
    run_dir = Path(run_dir)
    if run_dir.exists() and not run_dir.is_dir():
        raise AngiohullError(f"{run_dir}: not a directory")
    stored = run_dir / CONFIG_FILE
    if stored.exists():
        data = read_yaml_file(stored, error=ConfigError, what="the run's configuration")
        previous = config_from_dict(data, str(stored))
        if _canonical(previous) != _canonical(config):
            diffs = _differences(config_to_dict(previous), config_to_dict(config))
            raise ConfigError(
                f"{run_dir} holds a run of another configuration ({'; '.join(diffs[:5])}"
                f"{' ...' if len(diffs) > 5 else ''}); resume it with the same CONFIG and --quick setting, "
                f"or choose a new RUN_DIR")
        return run_dir
    if run_dir.exists() and any(run_dir.iterdir()):
        if (run_dir / ROWS_FILE).exists():
            raise AngiohullError(f"{run_dir} has {ROWS_FILE} but no {CONFIG_FILE}; choose a new RUN_DIR")
    run_dir.mkdir(parents=True, exist_ok=True)
    header = (f"# resolved configuration of the experiment run in this folder (angiohull {__version__});\n"
              f"# `angiohull experiment {stored} -o OTHER_DIR` reruns it\n")
    write_atomic(stored, header + yaml.safe_dump(config_to_dict(config), sort_keys=False))
    return run_dir


def _write_results(run_dir: Path, columns: Sequence[str], rows: dict[int, dict[str, Any]]) -> None:
    write_atomic(run_dir / RESULTS_FILE, rows_to_csv(columns, [rows[k] for k in sorted(rows)]))


def _status_counts(rows: dict[int, dict[str, Any]]) -> dict[str, int]:
    counts = {s: 0 for s in STATUSES}
    for row in rows.values():
        counts[row["status"]] = counts.get(row["status"], 0) + 1
    return counts


def _update_run_json(run_dir: Path, config: ExperimentConfig, total: int, rows: dict[int, dict[str, Any]],
                     invocation: dict[str, Any]) -> None:
    path = run_dir / RUN_FILE
    try:
        record = json.loads(path.read_text(encoding="utf-8")) if path.exists() else {}
    except (OSError, json.JSONDecodeError):
        record = {}
    invocations = [i for i in record.get("invocations", []) if i.get("started") != invocation["started"]]
    invocations.append(invocation)
    record = {
        "experiment": config.name,
        "mode": config.mode,
        "angiohull_version": __version__,
        "config_sha256": hashlib.sha256(_canonical(config).encode()).hexdigest(),
        "cases_total": total,
        "cases_done": len(rows),
        "status_counts": _status_counts(rows),
        "invocations": invocations,
    }
    write_atomic(path, json.dumps(record, indent=1) + "\n")


# -- executors --------------------------------------------------------------------------------------
def _ignore_sigint() -> None:  # pragma: no cover - runs in the worker processes
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _run_serial(cases: Sequence[dict[str, Any]]) -> Iterator[dict[str, Any]]:
    for params in cases:
        yield run_case(params)


def _run_processes(cases: Sequence[dict[str, Any]], workers: int) -> Iterator[dict[str, Any]]:
    context = multiprocessing.get_context("spawn")  # no fork of a process that may hold threads
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_ignore_sigint)
    pending = iter(cases)
    in_flight = set()
    try:
        for params in pending:
            in_flight.add(pool.submit(run_case, params))
            if len(in_flight) >= 2 * workers:
                break
        while in_flight:
            done, in_flight = wait(in_flight, return_when=FIRST_COMPLETED)
            for future in done:
                try:
                    row = future.result()
                except BrokenProcessPool:
                    raise AngiohullError(
                        "a worker process died (out of memory, killed, or started from a script without an "
                        "`if __name__ == '__main__':` guard); the finished rows are kept: rerun the same command "
                        "to resume") from None
                yield row
                following = next(pending, None)
                if following is not None:
                    in_flight.add(pool.submit(run_case, following))
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _connect_dask(address: str):
    """A client of the Dask scheduler at ``address`` (errors here, before any work starts)."""
    try:
        from distributed import Client
    except ImportError:
        raise AngiohullError("--scheduler needs dask.distributed: pip install 'angiohull[cluster]'") from None
    try:
        return Client(address, timeout=f"{DASK_CONNECT_TIMEOUT_S}s", set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise AngiohullError(f"cannot reach the Dask scheduler at {address} ({exc}); start one with "
                             f"`dask scheduler` and workers with `dask worker {address}`") from None


def _run_dask(cases: Sequence[dict[str, Any]], client) -> Iterator[dict[str, Any]]:
    from distributed import as_completed

    futures = []
    try:
        threads = max(1, sum(client.nthreads().values()))
        pending = iter(cases)
        first = [client.submit(run_case, p, pure=False) for _, p in zip(range(2 * threads), pending)]
        futures = list(first)
        queue = as_completed(first, loop=client.loop)
        for future in queue:
            row = future.result()
            futures.remove(future)
            future.release()
            yield row
            following = next(pending, None)
            if following is not None:
                new = client.submit(run_case, following, pure=False)
                futures.append(new)
                queue.add(new)
    finally:
        for future in futures:
            future.cancel()
        client.close()


# -- the run ----------------------------------------------------------------------------------------
def run_experiment(config: ExperimentConfig, run_dir: str | Path, *, workers: Optional[int] = None,
                   scheduler: Optional[str] = None, stream: Optional[TextIO] = sys.stderr,
                   max_cases: Optional[int] = None) -> RunSummary:
    """Run (or resume) every case of ``config`` into ``run_dir``.

    Parameters
    ----------
    config : ExperimentConfig
        Already resolved (``load_config(..., quick=...)``).
    run_dir : path
        Created if needed; if it holds a run of the same configuration, finished cases are skipped.
    workers : int, optional
        Local worker processes (default: the usable CPUs); 1 runs the cases in this process.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:port``); the cases run on its workers
        (``workers`` is then ignored).
    stream : text stream or None
        Where progress and the summary go (default stderr; None: silent).
    max_cases : int, optional
        Stop after this many new cases, as if interrupted (for tests and trial runs).

    Returns
    -------
    RunSummary
    """
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise AngiohullError(f"workers must be a whole number >= 1, got {workers!r}")
    cases = expand_cases(config)
    columns = row_columns(config)
    client = _connect_dask(scheduler) if scheduler is not None else None
    try:
        run_dir = prepare_run_dir(config, run_dir)
    except BaseException:
        if client is not None:
            client.close()
        raise
    write_atomic(run_dir / CASES_FILE, "".join(json.dumps(c, sort_keys=True) + "\n" for c in cases))
    journal = RowsJournal(run_dir / ROWS_FILE, columns)
    known = {int(r["case_id"]): r for r in journal.open()}
    total = len(cases)
    unknown = [k for k in known if not 0 <= k < total]
    if unknown:
        journal.close()
        if client is not None:
            client.close()
        raise AngiohullError(f"{run_dir / ROWS_FILE}: case_id {unknown[0]} is not a case of this experiment; "
                             f"choose a new RUN_DIR")
    pending = [c for c in cases if c["case_id"] not in known]
    if max_cases is not None:
        pending = pending[:max(0, int(max_cases))]
    if client is not None:
        executor, rows_iter = f"Dask scheduler {scheduler}", _run_dask(pending, client)
    else:
        workers = default_workers() if workers is None else workers
        if workers == 1 or len(pending) <= 1:
            executor, rows_iter = "this process", _run_serial(pending)
        else:
            executor, rows_iter = f"{workers} worker processes", _run_processes(pending, workers)
    summary = RunSummary(config.name, run_dir, total, len(known), 0, executor=executor)
    progress = _Progress(config.name, total, len(known), stream)
    started = datetime.now(timezone.utc).isoformat(timespec="seconds")
    if stream is not None:
        print(f"{config.name}: {total} cases ({config.mode}), {len(known)} already done; running {len(pending)} on "
              f"{executor}; engine {config.reconstruction.engine}, K={config.reconstruction.resolution or 'preset default'}, "
              f"preset {config.reconstruction.preset}",
              file=stream, flush=True)
    start = time.perf_counter()
    try:
        for row in rows_iter:
            journal.append(row)
            known[int(row["case_id"])] = row
            summary.done_now += 1
            progress.update(row)
    except KeyboardInterrupt:
        summary.interrupted = True
        raise
    finally:
        rows_iter.close()
        if client is not None:
            client.close()  # also when the generator never started (nothing pending)
        journal.close()
        summary.wall_s = time.perf_counter() - start
        summary.status_counts = _status_counts(known)
        if max_cases is not None and summary.done < total:
            summary.interrupted = True
        _write_results(run_dir, columns, known)
        _update_run_json(run_dir, config, total, known, {
            "started": started, "wall_s": round(summary.wall_s, 3), "cases_run": summary.done_now,
            "executor": executor, "interrupted": summary.interrupted, "python": platform.python_version(),
            "numpy": np.__version__, "machine": platform.machine(), "cpus": default_workers(),
        })
        if stream is not None:
            progress.show(final=True)
            print(summary.text(), file=stream, flush=True)
    return summary


@dataclass(frozen=True)
class RunData:
    """A run directory read back: its configuration, its rows (sorted by case) and its run record."""

    run_dir: Path
    config: ExperimentConfig
    columns: list[str]
    rows: list[dict[str, Any]]
    record: dict[str, Any]
    total: int


def load_run(run_dir: str | Path) -> RunData:
    """Read a run directory (``config.yaml`` and ``rows.csv``; the journal is the source of truth)."""
    run_dir = Path(run_dir)
    stored = run_dir / CONFIG_FILE
    if not stored.is_file():
        raise AngiohullError(f"{run_dir}: not a run directory (no {CONFIG_FILE}); run `angiohull experiment CONFIG "
                             f"-o {run_dir}` first")
    data = read_yaml_file(stored, error=ConfigError, what="the run's configuration")
    config = config_from_dict(data, str(stored))
    columns = row_columns(config)
    rows_path = run_dir / ROWS_FILE
    rows = read_rows(rows_path, columns)[1] if rows_path.exists() else []
    rows.sort(key=lambda r: r["case_id"])
    try:
        record = json.loads((run_dir / RUN_FILE).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        record = {}
    total = int(record.get("cases_total", len(expand_cases(config))))
    return RunData(run_dir, config, columns, rows, record, total)
