"""The versions of the numerical libraries a benchmark ran with, for its report: results move a
little between releases (measured: the 60 trees of benchmarks/qca.py at one commit gave a distal
angle MAE of 4.4 degrees with one set of releases and 4.55 with another)."""

from __future__ import annotations

from importlib import metadata

LIBRARIES = ("numpy", "scipy", "scikit-image", "vtk", "nibabel")


def library_versions() -> str:
    """``"numpy 2.4.6, scipy 1.17.1, ..."`` of the installed releases (read from their metadata,
    nothing imported); a library that is not installed is left out."""
    found = []
    for name in LIBRARIES:
        try:
            found.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            continue
    return ", ".join(found)
