"""Builds run in forked child processes while this one builds others (the ``tree`` method's
views' 2D centerline data, matchings and hypotheses, module notes of
:mod:`angiohull.reconstruction.model`).

On Linux with two CPUs or more and no other Python thread (:func:`_can_fork`) children are forked;
each runs the same code on the same arrays and sends its results back pickled through a pipe. No
other Python thread is running, so none holds a lock a child would need; the BLAS library's own
threads are fork-safe (multiprocessing's fork start method relies on it too).

:func:`_in_processes` gives each build a process of its own, up to twice the CPUs: the system then
shares the CPUs among the builds, and a set of builds ends when their total work over the CPUs is
done (or the longest build is). Three builds of equal length on two CPUs end after one and a half
builds' time, where two processes (two builds in one of them) would take two: measured on the
hypotheses of the benchmark's left tree seed 8001 (three builds), 1.72-1.85 s against 2.42-2.68 s.
"""

from __future__ import annotations

import os
import pickle
from typing import Callable, Sequence

__all__: list[str] = []


def _can_fork() -> bool:
    """Whether a process may be forked to build the alternative matchings' trees at the same time
    as the first one: Linux (where fork is the process model numpy and scipy are used under), two
    CPUs or more available to this process, and no other Python thread (a fork copies only the
    calling thread; a lock another thread held would stay held in the child)."""
    import sys
    import threading

    if not sys.platform.startswith("linux") or not hasattr(os, "fork") or threading.active_count() != 1:
        return False
    try:
        return len(os.sched_getaffinity(0)) >= 2
    except (AttributeError, OSError):
        return False


class _ForkedBuilds:
    """``build()`` run in a forked child, its pickled result read back by :meth:`result` (None if
    the child failed: the caller builds it itself). The child leaves by ``os._exit``: no buffered
    output of the parent's is written twice, no exit handler runs."""

    def __init__(self, build: Callable[[], object]):
        import warnings

        self._read, write = os.pipe()
        with warnings.catch_warnings():  # Python 3.12+ warns of any thread, BLAS's too (fork-safe: module notes)
            warnings.simplefilter("ignore", DeprecationWarning)
            self._pid = os.fork()
        if self._pid == 0:  # the child
            status = 1
            try:
                os.close(self._read)
                with os.fdopen(write, "wb") as out:
                    pickle.dump(build(), out, protocol=pickle.HIGHEST_PROTOCOL)
                status = 0
            finally:
                os._exit(status)
        os.close(write)

    def result(self) -> object | None:
        with os.fdopen(self._read, "rb") as stream:
            data = stream.read()
        _, status = os.waitpid(self._pid, 0)
        if status != 0 or not data:
            return None
        return pickle.loads(data)

    def abandon(self) -> None:
        """Stop the child (the parent's own build failed, or was interrupted)."""
        import signal

        try:
            os.kill(self._pid, signal.SIGKILL)
            os.waitpid(self._pid, 0)
        except (ProcessLookupError, ChildProcessError):
            pass
        try:
            os.close(self._read)
        except OSError:  # already closed by a result() that failed
            pass


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _in_processes(tasks: Sequence[Callable[[], object]], fork: bool) -> list:
    """The results of ``tasks`` in their order: where ``fork`` and :func:`_can_fork` allow, split
    into as many processes as there are tasks, at most twice the CPUs (module notes), in runs of
    consecutive tasks; the first run is built here, the others in forked children meanwhile (a
    child's run built here if the child fails; the children stopped if a task here raises)."""
    processes = min(len(tasks), 2 * _cpus()) if len(tasks) > 1 and fork and _can_fork() else 1
    if processes == 1:
        return [task() for task in tasks]
    bounds = [len(tasks) * k // processes for k in range(processes + 1)]
    runs = [tasks[bounds[k]:bounds[k + 1]] for k in range(processes)]
    forked: list[_ForkedBuilds] = []
    collected = 0
    try:
        for run in runs[1:]:
            forked.append(_ForkedBuilds(lambda run=run: [task() for task in run]))
        results = [task() for task in runs[0]]
        for child, run in zip(forked, runs[1:]):
            theirs = child.result()
            collected += 1
            results += [task() for task in run] if theirs is None else theirs  # a failed child: built here
    except BaseException:
        for child in forked[collected:]:
            child.abandon()
        raise
    return results
