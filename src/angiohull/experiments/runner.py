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
import warnings
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterator, Optional, Sequence, TextIO

import numpy as np
import yaml

from .. import __version__, compiled
from .._yaml import read_yaml_file
from ..errors import AngiohullError, InputWarning, OutputError
from .cases import STATUSES, expand_cases, row_columns, run_case
from .config import ConfigError, ExperimentConfig, config_from_dict, config_to_dict
from .rows import RowsJournal, read_rows, rows_to_csv, write_atomic

__all__ = ["RunSummary", "run_experiment", "prepare_run_dir", "default_workers", "load_run", "RunData",
           "CONFIG_FILE", "CASES_FILE", "ROWS_FILE", "RESULTS_FILE", "RUN_FILE", "LOCK_FILE"]

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
    if run_dir.exists():
        others = sorted(p.name for p in run_dir.iterdir() if not p.name.startswith("."))
        if (run_dir / ROWS_FILE).exists():
            raise AngiohullError(f"{run_dir} has {ROWS_FILE} but no {CONFIG_FILE}; choose a new RUN_DIR")
        if others:
            shown = ", ".join(others[:3]) + (f" and {len(others) - 3} more" if len(others) > 3 else "")
            raise AngiohullError(f"{run_dir}: is not empty (holds {shown}) and holds no run ({CONFIG_FILE}); a run "
                                 f"goes into a new or empty folder, or the folder of an earlier run to resume it")
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
    # one call per invocation: every earlier record is kept (two invocations may start within the
    # same second; the start time is no key)
    invocations = list(record.get("invocations", [])) + [invocation]
    record = {
        "experiment": config.name,
        "mode": config.mode,
        "angiohull_version": __version__,
        "config_sha256": hashlib.sha256(_canonical(config).encode()).hexdigest(),
        # the file's own bytes: `report` warns when config.yaml was edited after the rows were made
        "config_file_sha256": hashlib.sha256((run_dir / CONFIG_FILE).read_bytes()).hexdigest(),
        "cases_total": total,
        "cases_done": len(rows),
        "status_counts": _status_counts(rows),
        "invocations": invocations,
    }
    write_atomic(path, json.dumps(record, indent=1) + "\n")


# -- one runner per run directory ------------------------------------------------------------------
LOCK_FILE = ".angiohull.lock"
"""The lock file of a run directory: held (``flock``) by the runner working in it, with who that is."""


class _RunLock:
    """An exclusive ``flock`` on ``RUN_DIR/.angiohull.lock`` for as long as a runner works in the folder.

    The file records who holds it (pid, host, start time); the operating system releases the lock
    when the holder's process ends, however it ends, so a killed runner never blocks the next one.
    Where ``fcntl`` does not exist (Windows) no lock is taken.
    """

    def __init__(self, run_dir: Path):
        self.path = run_dir / LOCK_FILE
        self.handle = None

    def acquire(self) -> "_RunLock":
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX
            return self
        handle = open(self.path, "a+", encoding="utf-8")
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.seek(0)
            holder = handle.read().strip()
            handle.close()
            try:
                info = json.loads(holder)
                who = f"process {info['pid']} on {info['host']}, started {info['started']}"
            except (ValueError, KeyError, TypeError):
                who = "another process"
            raise AngiohullError(f"{self.path.parent}: another runner is working in this run directory ({who}); "
                                 f"wait for it to finish (or stop it), then run the same command to resume") from None
        handle.seek(0)
        handle.truncate()
        handle.write(json.dumps({"pid": os.getpid(), "host": platform.node(),
                                 "started": datetime.now(timezone.utc).isoformat(timespec="seconds")}) + "\n")
        handle.flush()
        self.handle = handle
        return self

    def release(self) -> None:
        if self.handle is not None:
            self.handle.close()  # closing the file releases the lock; the file stays (no race on its name)
            self.handle = None


# -- executors --------------------------------------------------------------------------------------
_PARENT_POLL_S = 1.0


def _worker_init(parent_pid: int) -> None:  # pragma: no cover - runs in the worker processes
    """Worker set-up: ignore SIGINT (the runner stops the pool), and end with the runner.

    A runner killed by SIGKILL (or SIGTERM, whose default action runs no clean-up) cannot stop its
    pool; its workers would run on for minutes. On Linux the kernel sends each worker SIGKILL when
    the runner dies (``prctl(PR_SET_PDEATHSIG)``); everywhere, a thread of each worker checks once a
    second that its parent is still the runner and ends the worker otherwise.
    """
    import threading

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            PR_SET_PDEATHSIG = 1
            libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:  # the runner died before the line above
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(_PARENT_POLL_S)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="angiohull-parent-watch", daemon=True).start()


def _run_serial(cases: Sequence[dict[str, Any]]) -> Iterator[dict[str, Any]]:
    for params in cases:
        yield run_case(params)


def _run_processes(cases: Sequence[dict[str, Any]], workers: int) -> Iterator[dict[str, Any]]:
    context = multiprocessing.get_context("spawn")  # no fork of a process that may hold threads
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_worker_init,
                               initargs=(os.getpid(),))
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


DASK_PROBE_TIMEOUT_S = 5.0
"""How long a TCP connection to the scheduler's address may take before the address counts as unreachable."""

_SCHEDULER_FORM = "tcp://HOST:PORT (e.g. tcp://10.0.0.5:8786), or tls://, ucx://, inproc:// addresses"


def _check_scheduler_address(address: str) -> None:
    """Fail fast on a malformed address, or a tcp:// / tls:// address nothing listens on (the Dask
    client itself retries until its timeout)."""
    import socket
    from urllib.parse import urlsplit

    if not isinstance(address, str) or not address.strip() or any(c.isspace() for c in address):
        raise AngiohullError(f"--scheduler: {address!r} is not a scheduler address; expected {_SCHEDULER_FORM}")
    text = address if "://" in address else f"tcp://{address}"
    try:
        parts = urlsplit(text)
        port = parts.port
    except ValueError as exc:
        raise AngiohullError(f"--scheduler: {address!r} is not a scheduler address ({exc}); expected "
                             f"{_SCHEDULER_FORM}") from None
    if parts.scheme not in ("tcp", "tls", "ucx", "inproc", "ws", "wss"):
        raise AngiohullError(f"--scheduler: {address!r} has an unknown protocol {parts.scheme!r}; expected {_SCHEDULER_FORM}")
    if parts.scheme not in ("tcp", "tls"):
        return
    if not parts.hostname or parts.path not in ("", "/") or parts.query or parts.fragment:
        raise AngiohullError(f"--scheduler: {address!r} is not a scheduler address; expected {_SCHEDULER_FORM}")
    host, port = parts.hostname, 8786 if port is None else port
    try:
        with socket.create_connection((host, port), timeout=DASK_PROBE_TIMEOUT_S):
            pass
    except socket.gaierror as exc:
        raise AngiohullError(f"--scheduler: cannot reach the Dask scheduler at {address}: unknown host {host!r} "
                             f"({exc.strerror or exc})") from None
    except OSError as exc:
        if isinstance(exc, TimeoutError):
            reason = f"no answer within {DASK_PROBE_TIMEOUT_S:g} s"
        else:
            reason = exc.strerror or str(exc) or type(exc).__name__
        raise AngiohullError(f"--scheduler: cannot reach the Dask scheduler at {address} ({reason}); start one with "
                             f"`dask scheduler` and workers with `dask worker {address}`") from None


def _connect_dask(address: str):
    """A client of the Dask scheduler at ``address`` (errors here, before any work starts)."""
    try:
        from distributed import Client
    except ImportError:
        raise AngiohullError("--scheduler needs dask.distributed: pip install 'angiohull[cluster]'") from None
    _check_scheduler_address(address)
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
    lock = None
    try:
        run_dir = prepare_run_dir(config, run_dir)
        lock = _RunLock(Path(run_dir)).acquire()
        return _run_locked(config, Path(run_dir), cases, columns, client, scheduler, workers, stream, max_cases)
    except OSError as exc:  # a full disk, a folder that cannot be written
        raise _write_error(exc, Path(run_dir)) from None
    finally:
        if lock is not None:
            lock.release()
        if client is not None:
            client.close()


def _write_error(exc: OSError, run_dir: Path) -> AngiohullError:
    import errno

    reason = exc.strerror or str(exc) or type(exc).__name__
    where = f" ({exc.filename})" if exc.filename else ""
    hint = "free some space" if exc.errno in (errno.ENOSPC, errno.EDQUOT) else "make the folder writable"
    return OutputError(f"cannot write the run into {run_dir}{where}: {reason}; every row finished before is kept "
                       f"whole in {ROWS_FILE}: {hint}, then run the same command to resume")


def _run_locked(config: ExperimentConfig, run_dir: Path, cases: list[dict[str, Any]], columns: list[str], client,
                scheduler: Optional[str], workers: Optional[int], stream: Optional[TextIO],
                max_cases: Optional[int]) -> RunSummary:
    """The run itself, with the run directory prepared and locked."""
    write_atomic(run_dir / CASES_FILE, "".join(json.dumps(c, sort_keys=True) + "\n" for c in cases))
    journal = RowsJournal(run_dir / ROWS_FILE, columns)
    known = {int(r["case_id"]): r for r in journal.open()}
    total = len(cases)
    unknown = [k for k in known if not 0 <= k < total]
    if unknown:
        journal.close()
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
            "kernels": compiled.status(),  # in this process; workers started here inherit its environment
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
    record: dict[str, Any] = {}
    if (run_dir / RUN_FILE).exists():
        try:
            loaded = json.loads((run_dir / RUN_FILE).read_text(encoding="utf-8"))
            record = loaded if isinstance(loaded, dict) else {}
            if not isinstance(loaded, dict):
                raise ValueError(f"holds a {type(loaded).__name__}, not an object")
        except (OSError, ValueError) as exc:  # (json.JSONDecodeError is a ValueError)
            warnings.warn(f"{run_dir / RUN_FILE}: cannot be read ({exc}); the report goes on without the run's record "
                          f"(its wall time and where it ran)", InputWarning, stacklevel=2)
        stored_sha = record.get("config_file_sha256")  # (runs before 2026-12-07 have none)
        if stored_sha is not None and stored_sha != hashlib.sha256(stored.read_bytes()).hexdigest():
            warnings.warn(f"{stored}: edited after the rows were made (its bytes differ from those {RUN_FILE} "
                          f"recorded, config_file_sha256); the report describes the file as it is now, which may not "
                          f"be the experiment that ran", InputWarning, stacklevel=2)
        recorded = record.get("cases_done")  # the journal's rows when the last invocation ended
        if isinstance(recorded, int) and not isinstance(recorded, bool) and len(rows) < recorded:
            held = f"holds {len(rows)} finished case(s)" if rows_path.exists() else "is missing"
            warnings.warn(f"{rows_path}: {held}, but {RUN_FILE} recorded {recorded} when the run last ended: rows were "
                          f"lost (the file was cut short, replaced or edited); the report covers the {len(rows)} there "
                          f"are; running the same experiment into {run_dir} runs the missing cases again",
                          InputWarning, stacklevel=2)
    total = int(record.get("cases_total", len(expand_cases(config))))
    return RunData(run_dir, config, columns, rows, record, total)
