"""Builds run in a forked child process while this one builds others (the ``tree`` method's
matchings and hypotheses, module notes of :mod:`angiohull.reconstruction.model`).

On Linux with two CPUs or more and no other Python thread (:func:`_can_fork`) a child is forked;
it runs the same code on the same arrays and sends its results back pickled through a pipe. No
other Python thread is running, so none holds a lock the child would need; the BLAS library's own
threads are fork-safe (multiprocessing's fork start method relies on it too).
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
        os.close(self._read)


def _in_two_processes(tasks: Sequence[Callable[[], object]], fork: bool) -> list:
    """The results of ``tasks`` in their order: the first half run here and, where ``fork`` and
    :func:`_can_fork` allow, the second half in a forked child meanwhile (built here if the child
    fails; the child stopped if a task here raises)."""
    half = (len(tasks) + 1) // 2
    forked = (_ForkedBuilds(lambda: [task() for task in tasks[half:]])
              if len(tasks) > 1 and fork and _can_fork() else None)
    if forked is None:
        return [task() for task in tasks]
    try:
        mine = [task() for task in tasks[:half]]
    except BaseException:
        forked.abandon()
        raise
    theirs = forked.result()
    if theirs is None:  # the child failed: built here
        theirs = [task() for task in tasks[half:]]
    return mine + theirs
