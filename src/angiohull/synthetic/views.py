"""Named sets of C-arm views for synthetic studies, and the ``--views`` syntax of ``angiohull synth``."""

from __future__ import annotations

from typing import Sequence

from ..errors import AngiohullError
from ..geometry import CArmGeometry, parse_clinical_angles

__all__ = ["VIEW_SETS", "parse_views", "carm_views", "view_name"]

VIEW_SETS: dict[str, tuple[str, ...]] = {
    # The paper's "perpendicular" views: beams along the three world axes (posterior -> anterior,
    # right -> left, feet -> head), as in the authors' own synthetic data.
    "perpendicular": ("AP", "LAO 90", "CRA 90"),
    # The paper's clinical views.
    "clinical": ("RAO 30 CRA 30", "LAO 60 CRA 30", "RAO 30 CAU 30"),
}


def view_name(text: str) -> str:
    """A file-name-safe view name from a clinical string: ``"RAO 30 CRA 30"`` -> ``"RAO30_CRA30"``."""
    words = text.replace(",", " ").split()
    parts: list[str] = []
    for word in words:
        if parts and word.replace(".", "", 1).lstrip("+-").isdigit():
            parts[-1] += word
        else:
            parts.append(word.upper())
    return "_".join(parts)


def parse_views(spec: str | Sequence[str]) -> list[tuple[str, float, float]]:
    """Views as ``(name, primary_deg, secondary_deg)``.

    Parameters
    ----------
    spec : str or sequence of str
        ``"perpendicular"``, ``"clinical"`` (see :data:`VIEW_SETS`), or clinical angle strings
        separated by ``;`` (``"RAO 30 CRA 30; LAO 60 CRA 30"``), or a sequence of such strings.

    Raises
    ------
    AngiohullError
        If no view is given, a view cannot be parsed, or two views have the same angles.
    """
    if isinstance(spec, str):
        key = spec.strip().lower()
        items = list(VIEW_SETS[key]) if key in VIEW_SETS else [s.strip() for s in spec.split(";")]
    else:
        items = [str(s).strip() for s in spec]
    items = [s for s in items if s]
    if not items:
        raise AngiohullError(f"views: expected at least one view, e.g. 'RAO 30 CRA 30; LAO 60 CRA 30' or one of "
                             f"{', '.join(VIEW_SETS)}; got {spec!r}")
    views = []
    seen: dict[tuple[float, float], str] = {}
    for text in items:
        try:
            primary, secondary = parse_clinical_angles(text)
        except ValueError as exc:
            raise AngiohullError(f"views: {exc}") from None
        if (primary, secondary) in seen:
            raise AngiohullError(f"views: {text!r} repeats the angles of {seen[(primary, secondary)]!r}")
        seen[(primary, secondary)] = text
        views.append((view_name(text), primary, secondary))
    return views


def carm_views(spec: str | Sequence[str], *, sid_mm: float = 1200.0, sod_mm: float = 800.0,
               pixel_mm: float = 0.35, size: int = 512) -> list[tuple[str, CArmGeometry]]:
    """:func:`parse_views` turned into C-arm geometries with square pixels and a square detector.

    Defaults are the paper's: SID 1200 mm, SOD 800 mm, 0.35 mm pixels, 512 x 512.
    """
    out = []
    for name, primary, secondary in parse_views(spec):
        carm = CArmGeometry(primary_deg=primary, secondary_deg=secondary, sid_mm=sid_mm, sod_mm=sod_mm,
                            pixel_spacing_mm=(pixel_mm, pixel_mm), image_shape=(size, size))
        out.append((name, carm))
    return out
