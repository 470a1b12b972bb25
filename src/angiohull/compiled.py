"""Optional compiled kernels for the hot loops (``pip install "angiohull[fast]"``: numba).

The carving, the Guo–Hall thinning, the centerline step's nearest-neighbour search, the
calibration's distances to a 2D centreline and dilations, the refined preset's nearest axis points
and rivals and the tree method's lattice points in tubes, tube silhouettes and the slide's disc
counts, junction pixel counts, cross-section runs, spoiled runs, pixel matching (min-sum over a
forest), the TEASAR paths' voxel graph (its CSR rows built directly) and their cover (each voxel's
nearest path voxels, the k-d tree asked where they disagree) each have a NumPy implementation,
which is the reference, and a compiled one
(:mod:`angiohull._numba_kernels`) that computes the same thing with the same arithmetic: the same
points, skeletons and neighbours bit for bit (the tests compare them).

The library uses the compiled kernels when numba can be imported; the environment variable
``ANGIOHULL_COMPILED=0`` (or :func:`set_enabled`, :func:`disabled`) runs the NumPy code instead.
The command line chooses per command where ``ANGIOHULL_COMPILED`` is unset
(:func:`angiohull.cli.main`: loading numba costs about 0.4 s a process). The first call of a
kernel on a machine compiles it (about 30 s for all, once); later processes load it from numba's
cache (at a terminal, a note on stderr says when it compiles).
"""

from __future__ import annotations

import contextlib
import os
import sys
from types import ModuleType
from typing import Iterator

__all__ = ["kernels", "set_enabled", "disabled", "status", "chosen_by_environment"]

_OFF = {"0", "no", "false", "off"}
_state: dict[str, object] = {"enabled": os.environ.get("ANGIOHULL_COMPILED", "1").strip().lower() not in _OFF,
                             "module": None, "error": None, "why_off": "compiled kernels disabled"}


def chosen_by_environment() -> bool:
    """Whether ``ANGIOHULL_COMPILED`` is set (to anything): then the command line leaves the choice
    to it (see :func:`angiohull.cli.main`)."""
    return bool(os.environ.get("ANGIOHULL_COMPILED", "").strip())


def kernels() -> ModuleType | None:
    """The compiled kernels' module, or None when they are disabled or numba is not installed."""
    if not _state["enabled"]:
        return None
    if _state["module"] is None and _state["error"] is None:
        try:
            from . import _numba_kernels
        except Exception as exc:  # noqa: BLE001 - numba absent, broken, or unable to cache: the NumPy code runs
            _state["error"] = f"{type(exc).__name__}: {exc}"
        else:
            _state["module"] = _numba_kernels
            if _interactive() and not _cached(_numba_kernels):
                sys.stderr.write("angiohull: compiling the numba kernels, once for this installation (about 30 s; "
                                 "ANGIOHULL_COMPILED=0 runs the NumPy code instead)\n")
    return _state["module"]  # type: ignore[return-value]


def _interactive() -> bool:
    """Whether stderr is a terminal: the compile note is for a person waiting at one."""
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError):
        return False


def _cached(module: ModuleType) -> bool:
    """Whether numba's cache holds the main kernels (read from numba's cache objects; True when
    that cannot be told, so that the note is only ever written when it is due)."""
    try:
        return all(os.path.exists(getattr(module, name)._cache._cache_file._index_path)
                   for name in ("carve_lattice", "guo_hall_thin_flat", "nearest_2d_with_ties"))
    except Exception:  # noqa: BLE001 - numba's private layout changed: say nothing
        return True


def set_enabled(enabled: bool, *, why_off: str = "compiled kernels disabled") -> bool:
    """Use the compiled kernels (where numba is installed) or not; returns the previous setting.
    ``why_off`` is what :func:`status` says while they are off."""
    previous = bool(_state["enabled"])
    _state["enabled"] = bool(enabled)
    _state["why_off"] = why_off
    return previous


@contextlib.contextmanager
def disabled() -> Iterator[None]:
    """Run the NumPy reference code inside the block."""
    previous = set_enabled(False)
    try:
        yield
    finally:
        set_enabled(previous)


def status() -> str:
    """One line for reports: whether the compiled kernels run, and why not."""
    if not _state["enabled"]:
        return f"NumPy ({_state['why_off']})"
    module = kernels()
    if module is None:
        return f"NumPy (numba not available: {_state['error']})"
    import numba

    return f"numba {numba.__version__}"
