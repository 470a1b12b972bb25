"""The interactive 3D viewer of a reconstruction: one self-contained HTML file (``viewer.html``).

This module belongs to the viz layer, at the top of the stack: only the CLI imports it. The page
embeds plotly.js (from the ``plotly`` Python package, read as a file: plotly's Python API is never
imported) and the scene as JSON, so it opens offline, from a file or a mail attachment, in any
browser with WebGL. Arrays travel as little-endian base64 typed arrays (plotly.js's ``bdata``
form: float32 coordinates, int32 face indices), about 5.3 characters per coordinate.

Layers (legend entries; a click toggles one, a double click isolates it):

* **vessel surface**: the tree's watertight mesh (:mod:`angiohull.tree.solid`), decimated by
  vertex clustering above :data:`MAX_MESH_FACES` faces;
* **lumen points**: the carved lattice points (shown when there is no mesh, else off), an even
  subset above :data:`MAX_POINTS` (:data:`MAX_POINTS_UNDER_MESH` under a mesh);
* **centerlines**: the vessel tree's branches, coloured by radius (colour bar in mm); without a
  tree, the centerline points;
* **lesions**: the minimal-lumen-diameter point of each lesion of a quantitative analysis, with
  MLD, %DS, length and the best working view on hover;
* **ground truth**, **true centerlines** and the **error** layers (off at first; the "truth &
  error" button shows them): every shown lumen point and tree point coloured by its distance to the
  truth, mm (:func:`truth_distances_mm`);
* per view, **its source and detector** (the detector's rectangle, the central ray and the source
  with the view's name) and **its X-ray cone** (rays from the source to the detector's corners):
  off at first, the "views" and "X-ray cones" buttons show all of them.

:func:`viewer_html` returns the page; :func:`write_viewer` writes it atomically.
"""

from __future__ import annotations

import base64
import html
import json
import math
import os
import secrets
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from .errors import OutputError, ViewerError
from .geometry import Projection

__all__ = ["ViewerView", "viewer_html", "write_viewer", "plotly_js", "truth_distances_mm", "decimate_mesh",
           "even_subset", "MAX_POINTS", "MAX_POINTS_UNDER_MESH", "MAX_MESH_FACES", "MAX_TRUTH_POINTS",
           "FIGURE_ELEMENT_ID"]

#: Most lumen points drawn when they are the main layer (no mesh).
MAX_POINTS = 60_000
#: Most lumen points drawn when a mesh is shown (the points are then a layer that starts hidden).
MAX_POINTS_UNDER_MESH = 15_000
#: Most mesh faces drawn; above it the mesh is decimated by vertex clustering.
MAX_MESH_FACES = 40_000
#: Most ground-truth points drawn.
MAX_TRUTH_POINTS = 15_000
#: The id of the ``<script type="application/json">`` element that holds the scene.
FIGURE_ELEMENT_ID = "angiohull-figure"

_SURFACE_COLOUR = "#c8574a"
_SURFACE_OPACITY = 0.45  # the centerlines inside stay visible
_POINT_COLOUR = "#5b7db1"
_TRUTH_COLOUR = "#7f7f7f"
_TRUE_CENTERLINE_COLOUR = "#222222"
_LESION_COLOUR = "#d55e00"  # Okabe–Ito vermillion, as in the QCA figures
_VIEW_COLOURS = ("#0072b2", "#009e73", "#cc79a7", "#e69f00", "#56b4e9", "#f0e442", "#000000")
_RADIUS_SCALE = "Viridis"
_RADIUS_LEGEND_COLOUR = "#21918c"  # Viridis at its middle, for the centerlines' legend entry
# blue (near the truth) through amber to red (far): visible on white at every level; as in figure.png
_ERROR_SCALE = [[0.0, "#2b5ba8"], [0.5, "#e6a100"], [1.0, "#b2182b"]]


@dataclass(frozen=True)
class ViewerView:
    """One acquired view as the viewer draws it."""

    name: str
    projection: Projection
    sid_mm: float | None = None  # source-to-detector distance, mm (C-arm views); None: 1.5 x source-to-isocentre


# -- inputs ------------------------------------------------------------------------------------------
def _points(value: Any, name: str) -> np.ndarray:
    if value is None:
        return np.empty((0, 3))
    array = np.asarray(value, dtype=np.float64)
    if array.size == 0:
        return np.empty((0, 3))
    if array.ndim != 2 or array.shape[1] != 3:
        raise ViewerError(f"{name} must be an (N, 3) array of x, y, z in mm, got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ViewerError(f"{name} holds non-finite values (NaN or inf)")
    return array


def plotly_js() -> str:
    """The text of plotly.js as the installed ``plotly`` package ships it.

    Raises
    ------
    ViewerError
        If the ``plotly`` package is not installed.
    """
    from importlib.resources import files

    try:
        return (files("plotly") / "package_data" / "plotly.min.js").read_text(encoding="utf-8")
    except ModuleNotFoundError:
        raise ViewerError("the viewer needs the Python package plotly (pip install plotly); or skip the viewer "
                          "with --no-viewer") from None
    except (FileNotFoundError, OSError):  # an unusual plotly build: ask its own API
        from plotly.offline import get_plotlyjs

        return get_plotlyjs()


def even_subset(n: int, limit: int) -> np.ndarray:
    """Indices of at most ``limit`` of ``n`` items, evenly spread and increasing (all when n <= limit)."""
    if n <= limit:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, limit).round().astype(np.int64))


def decimate_mesh(vertices: np.ndarray, faces: np.ndarray, max_faces: int) -> tuple[np.ndarray, np.ndarray, float]:
    """A mesh with at most ``max_faces`` faces by vertex clustering.

    Vertices are snapped to a cubic grid of cell ``h`` (mm) and each cell's vertices replaced by
    their mean; faces that lose a corner that way, and repeated faces, are dropped. ``h`` starts at
    the mean edge length times ``sqrt(F / max_faces)`` and grows by 25 % until the mesh fits.

    Returns
    -------
    (vertices (V', 3), faces (F', 3), h)
        ``h`` is 0.0 when the mesh already fits (then it is returned unchanged).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) <= max_faces:
        return vertices, faces, 0.0
    edges = np.linalg.norm(vertices[faces[:, 1]] - vertices[faces[:, 0]], axis=1)
    cell = float(edges.mean()) * math.sqrt(len(faces) / max_faces)
    origin = vertices.min(axis=0)
    for _ in range(40):
        keys = np.floor((vertices - origin) / cell).astype(np.int64)
        _, cluster, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
        cluster = cluster.ravel()
        sums = np.zeros((len(counts), 3))
        np.add.at(sums, cluster, vertices)
        new_faces = cluster[faces]
        keep = ((new_faces[:, 0] != new_faces[:, 1]) & (new_faces[:, 1] != new_faces[:, 2])
                & (new_faces[:, 0] != new_faces[:, 2]))
        new_faces = new_faces[keep]
        # the same triangle twice (in any rotation) once: compare the sorted corners
        _, first = np.unique(np.sort(new_faces, axis=1), axis=0, return_index=True)
        new_faces = new_faces[np.sort(first)]
        if len(new_faces) <= max_faces:
            used = np.unique(new_faces)
            remap = np.full(len(counts), -1, dtype=np.int64)
            remap[used] = np.arange(len(used))
            return (sums[used] / counts[used, None]), remap[new_faces], cell
        cell *= 1.25
    raise ViewerError(f"cannot decimate a mesh of {len(faces)} faces to {max_faces}")  # pragma: no cover


def truth_distances_mm(points_mm: Any, truth_mm: Any) -> np.ndarray:
    """Distance (mm) from each point to the nearest truth point (a k-d tree, exact)."""
    from scipy.spatial import cKDTree

    points, truth = _points(points_mm, "points_mm"), _points(truth_mm, "truth_mm")
    if len(points) == 0:
        return np.empty(0)
    if len(truth) == 0:
        return np.full(len(points), np.nan)
    return cKDTree(truth).query(points)[0]


# -- encoding ----------------------------------------------------------------------------------------
def _typed(array: Any, dtype: str) -> dict[str, str]:
    """plotly.js's typed-array form: ``{"dtype": "f4", "bdata": base64 of the little-endian bytes}``."""
    numpy_type = {"f4": "<f4", "i4": "<i4", "u2": "<u2"}[dtype]
    data = np.ascontiguousarray(np.asarray(array), dtype=numpy_type)
    return {"dtype": dtype, "bdata": base64.b64encode(data.tobytes()).decode("ascii")}


def _xyz(points: np.ndarray) -> dict[str, Any]:
    return {"x": _typed(points[:, 0], "f4"), "y": _typed(points[:, 1], "f4"), "z": _typed(points[:, 2], "f4")}


def _polylines(lines: Sequence[np.ndarray]) -> np.ndarray:
    """Polylines joined into one array with a NaN row between them (a gap in a plotly line)."""
    parts: list[np.ndarray] = []
    for line in lines:
        if parts:
            parts.append(np.full((1, line.shape[1]), np.nan))
        parts.append(line)
    return np.concatenate(parts) if parts else np.empty((0, 3))


def _text(value: Any) -> str:
    """User text (names) for plotly's labels, which read a few HTML tags: escaped."""
    return html.escape(str(value), quote=False)


def _colour_limit(values: np.ndarray, floor: float) -> float:
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return floor
    return float(max(floor, np.percentile(finite, 95)))


# -- the scene ---------------------------------------------------------------------------------------
def _view_geometry(view: ViewerView) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Source (3,), detector corners (4, 3) in order around the rectangle, detector centre (3,)."""
    p = view.projection
    source = p.camera_centre_mm
    rows, cols = p.image_shape
    left = p.matrix[:, :3]
    scale = float(np.linalg.norm(left[2]))
    distance = view.sid_mm if view.sid_mm is not None else 1.5 * float(np.linalg.norm(source))
    # X = C + t M^-1 (u, v, 1) has depth t / |m3| (Projection.depth_mm) along the principal axis
    pixels = np.array([[-0.5, -0.5, 1.0], [cols - 0.5, -0.5, 1.0], [cols - 0.5, rows - 0.5, 1.0],
                       [-0.5, rows - 0.5, 1.0]])
    u0, v0 = p.principal_point_px
    directions = np.linalg.solve(left, np.vstack([pixels, [u0, v0, 1.0]]).T).T
    points = source + distance * scale * directions
    return source, points[:4], points[4]


def _view_traces(views: Sequence[ViewerView]) -> tuple[list[dict], list[int], list[int]]:
    traces: list[dict] = []
    frames, cones = [], []
    for i, view in enumerate(views):
        colour = _VIEW_COLOURS[i % len(_VIEW_COLOURS)]
        name = _text(view.name)
        source, corners, centre = _view_geometry(view)
        group = f"view-{i}"
        frame = np.vstack([corners, corners[:1]])
        frames.append(len(traces))
        traces.append({"type": "scatter3d", "mode": "lines", **_xyz(_polylines([frame, np.vstack([source, centre])])),
                       "line": {"color": colour, "width": 4}, "name": f"{name}: source, detector",
                       "legendgroup": group, "visible": "legendonly", "hoverinfo": "name"})
        frames.append(len(traces))
        traces.append({"type": "scatter3d", "mode": "markers+text", **_xyz(source[None, :]),
                       "marker": {"color": colour, "size": 7, "symbol": "circle"}, "text": [f"{name} source"],
                       "textposition": "top center", "textfont": {"color": colour}, "name": f"{name}: source",
                       "legendgroup": group, "showlegend": False, "visible": "legendonly",
                       "hovertext": [f"{name}: X-ray source ({source[0]:.0f}, {source[1]:.0f}, {source[2]:.0f}) mm"],
                       "hoverinfo": "text"})
        cones.append(len(traces))
        rays = _polylines([np.vstack([source, corner]) for corner in corners])
        traces.append({"type": "scatter3d", "mode": "lines", **_xyz(rays),
                       "line": {"color": colour, "width": 2, "dash": "dash"}, "name": f"{name}: X-ray cone",
                       "legendgroup": f"cone-{i}", "visible": "legendonly", "hoverinfo": "name"})
    return traces, frames, cones


def _lesion_trace(lesions: Sequence[Mapping[str, Any]]) -> dict:
    points, labels, hover = [], [], []
    for i, row in enumerate(lesions):
        try:
            point = [float(row["x_mm"]), float(row["y_mm"]), float(row["z_mm"])]
            mld, ds, length = float(row["mld_mm"]), float(row["diameter_stenosis_pct"]), float(row["lesion_length_mm"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ViewerError(f"lesions[{i}] needs numbers x_mm, y_mm, z_mm, mld_mm, diameter_stenosis_pct and "
                              f"lesion_length_mm (a row of qca.json's \"lesions\"); {exc!r}") from None
        if not all(math.isfinite(v) for v in (*point, mld, ds, length)):
            raise ViewerError(f"lesions[{i}]: position, MLD, %DS and length must be finite numbers")
        branch = row.get("branch")
        name = row.get("branch_name") or ""
        where = f"branch {branch}" + (f" ({_text(name)})" if name else "") if branch is not None else ""
        text = [f"<b>lesion {i}</b> {where}".rstrip(), f"MLD {mld:.2f} mm", f"%DS {ds:.0f} %",
                f"length {length:.1f} mm"]
        reference = row.get("reference_diameter_mm")
        if isinstance(reference, (int, float)) and math.isfinite(reference):
            text.insert(2, f"reference {float(reference):.2f} mm")
        best = row.get("best_view")
        text.append(f"best view {_text(best)}" if best else "best view: not computed")
        points.append(point)
        labels.append(f"L{i}")
        hover.append("<br>".join(text))
    array = np.array(points, dtype=np.float64).reshape(-1, 3)
    return {"type": "scatter3d", "mode": "markers+text", **_xyz(array), "text": labels, "textposition": "top center",
            "textfont": {"color": _LESION_COLOUR, "size": 13}, "hovertext": hover, "hoverinfo": "text",
            "marker": {"symbol": "diamond", "size": 7, "color": _LESION_COLOUR, "line": {"color": "black", "width": 1}},
            "name": f"lesions ({len(points)})"}


def _tree_lines(tree: Any) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The tree's branches as one gapped polyline: points, radius (NaN in the gaps), hover text."""
    lines, radii, text = [], [], []
    for b, branch in enumerate(tree.branches):
        points = branch.points_mm
        if branch.parent is not None:  # start at the parent's point so the drawing is connected
            parent_point = tree.branches[branch.parent].points_mm[branch.parent_point]
            if not np.array_equal(parent_point, points[0]):
                points = np.vstack([parent_point, points])
                radius = np.concatenate([[branch.radius_mm[0]], branch.radius_mm])
            else:
                radius = branch.radius_mm
        else:
            radius = branch.radius_mm
        lines.append(points)
        radii.append(radius)
        label = f"branch {b}" + (f" ({_text(branch.name)})" if branch.name else "")
        text.extend(f"{label}<br>radius {r:.2f} mm" for r in radius)
        text.append("")
    joined = _polylines(lines)
    radius = _polylines([r[:, None] for r in radii])[:, 0]
    return joined, radius, text[:-1]


@dataclass(frozen=True)
class _Scene:
    traces: list
    groups: dict
    meta: dict


def _scene(*, vessel_points_mm: Any, mesh_vertices_mm: Any, mesh_faces: Any, tree: Any, centerline_points_mm: Any,
           views: Sequence[ViewerView], ground_truth_mm: Any, ground_truth_tree: Any,
           lesions: Sequence[Mapping[str, Any]]) -> _Scene:
    vessel = _points(vessel_points_mm, "vessel_points_mm")
    truth = _points(ground_truth_mm, "ground_truth_mm")
    has_truth = len(truth) > 0
    traces: list[dict] = []
    groups: dict[str, list[int]] = {"truth": []}
    meta: dict[str, Any] = {"vessel_points": int(len(vessel))}

    has_mesh = mesh_vertices_mm is not None and mesh_faces is not None and np.size(mesh_faces) > 0
    if has_mesh:
        vertices = _points(mesh_vertices_mm, "mesh_vertices_mm")
        faces = np.asarray(mesh_faces)
        if faces.ndim != 2 or faces.shape[1] != 3 or faces.dtype.kind not in "iu":
            raise ViewerError(f"mesh_faces must be an (F, 3) integer array, got shape {faces.shape}, dtype {faces.dtype}")
        if faces.min() < 0 or faces.max() >= len(vertices):
            raise ViewerError(f"mesh_faces index vertices 0..{len(vertices) - 1}, got {faces.min()}..{faces.max()}")
        shown_vertices, shown_faces, cell = decimate_mesh(vertices, faces, MAX_MESH_FACES)
        meta["mesh"] = {"vertices": int(len(vertices)), "faces": int(len(faces)),
                        "shown_vertices": int(len(shown_vertices)), "shown_faces": int(len(shown_faces)),
                        "decimation_cell_mm": cell}
        index_type = "u2" if len(shown_vertices) <= 65536 else "i4"  # 2 bytes an index where they fit
        traces.append({"type": "mesh3d", **_xyz(shown_vertices), "i": _typed(shown_faces[:, 0], index_type),
                       "j": _typed(shown_faces[:, 1], index_type), "k": _typed(shown_faces[:, 2], index_type),
                       "color": _SURFACE_COLOUR, "opacity": _SURFACE_OPACITY, "flatshading": False,
                       "name": "vessel surface", "showlegend": True,
                       "hoverinfo": "skip", "showscale": False,
                       "lighting": {"ambient": 0.45, "diffuse": 0.75, "specular": 0.25, "roughness": 0.45,
                                    "fresnel": 0.2},
                       "lightposition": {"x": -1000, "y": -2000, "z": 3000}})

    if len(vessel):
        keep = even_subset(len(vessel), MAX_POINTS_UNDER_MESH if has_mesh else MAX_POINTS)
        shown = vessel[keep]
        meta["shown_vessel_points"] = int(len(shown))
        traces.append({"type": "scatter3d", "mode": "markers", **_xyz(shown),
                       "marker": {"size": 2, "color": _POINT_COLOUR, "opacity": 0.85},
                       "name": f"lumen points ({len(vessel):,})",
                       "visible": "legendonly" if has_mesh else True, "hoverinfo": "skip"})
    else:
        shown = np.empty((0, 3))
        meta["shown_vessel_points"] = 0

    tree_points = np.empty((0, 3))
    if tree is not None:
        line, radius, text = _tree_lines(tree)
        low, high = tree.radius_range_mm
        traces.append({"type": "scatter3d", "mode": "lines", **_xyz(line), "text": text, "hoverinfo": "text",
                       "line": {"color": _typed(radius, "f4"), "colorscale": _RADIUS_SCALE, "cmin": low,
                                "cmax": high if high > low else low + 0.1, "width": 7, "showscale": True,
                                "colorbar": {"title": {"text": "radius (mm)"}, "x": 1.0, "len": 0.45, "y": 0.75,
                                             "thickness": 14}},
                       "name": f"centerlines: radius ({tree.n_branches} branches)", "connectgaps": False,
                       "legendgroup": "centerlines", "showlegend": False})
        # its legend entry: plotly draws the swatch of a line coloured by an array in black, warning "Invalid
        # color specifier" in the console; a pointless line of one colour stands in for it (same group: a click
        # on it toggles the centerlines)
        traces.append({"type": "scatter3d", "mode": "lines", "x": [None], "y": [None], "z": [None],
                       "line": {"color": _RADIUS_LEGEND_COLOUR, "width": 7}, "hoverinfo": "skip",
                       "name": f"centerlines: radius ({tree.n_branches} branches)", "legendgroup": "centerlines",
                       "meta": "legend entry"})
        tree_points = line[np.isfinite(line[:, 0])]
        meta["tree"] = {"branches": int(tree.n_branches), "points": int(len(tree_points))}
    else:
        centerline = _points(centerline_points_mm, "centerline_points_mm")
        if len(centerline):
            traces.append({"type": "scatter3d", "mode": "markers", **_xyz(centerline),
                           "marker": {"size": 3, "color": "#d62728"}, "name": f"centerline points ({len(centerline):,})",
                           "hoverinfo": "skip"})
            tree_points = centerline
            meta["centerline_points"] = int(len(centerline))

    if has_truth:
        keep = even_subset(len(truth), MAX_TRUTH_POINTS)
        groups["truth"].append(len(traces))
        traces.append({"type": "scatter3d", "mode": "markers", **_xyz(truth[keep]),
                       "marker": {"size": 1.5, "color": _TRUTH_COLOUR, "opacity": 0.35},
                       "name": f"ground truth ({len(truth):,} points)",
                       "visible": "legendonly", "hoverinfo": "skip"})
        meta["truth_points"] = int(len(truth))
        meta["shown_truth_points"] = int(len(keep))
    if ground_truth_tree is not None:
        true_line, _, _ = _tree_lines(ground_truth_tree)
        groups["truth"].append(len(traces))
        traces.append({"type": "scatter3d", "mode": "lines", **_xyz(true_line),
                       "line": {"color": _TRUE_CENTERLINE_COLOUR, "width": 3}, "name": "true centerlines",
                       "visible": "legendonly", "hoverinfo": "name", "connectgaps": False})

    if has_truth or ground_truth_tree is not None:
        errors = []
        if has_truth and len(shown):
            point_error = truth_distances_mm(shown, truth)
            errors.append(("lumen points", shown, point_error, "nearest truth point"))
        if len(tree_points):
            if ground_truth_tree is not None:
                from .metrics.tree import distance_to_centerline

                line_error = distance_to_centerline(tree_points, ground_truth_tree)[0]
                against = "true centerline"
            else:
                line_error = truth_distances_mm(tree_points, truth)
                against = "nearest truth point"
            errors.append(("centerline", tree_points, line_error, against))
        # as in figure.png: at least 3 mm (the paper's voxel), so that sampling alone does not look like error
        limit = _colour_limit(np.concatenate([e[2] for e in errors]) if errors else np.empty(0), 3.0)
        meta["error_colour_limit_mm"] = limit
        for k, (label, points, error, against) in enumerate(errors):
            groups["truth"].append(len(traces))
            meta[f"error_{label.replace(' ', '_')}"] = {"against": against, "mean_mm": float(np.mean(error)),
                                                        "max_mm": float(np.max(error))}
            traces.append({"type": "scatter3d", "mode": "markers", **_xyz(points),
                           "marker": {"size": 2.5 if label == "lumen points" else 3.5, "color": _typed(error, "f4"),
                                      "colorscale": _ERROR_SCALE, "cmin": 0.0, "cmax": limit, "showscale": k == 0,
                                      "colorbar": {"title": {"text": "distance to<br>truth (mm)"}, "x": 1.0,
                                                   "len": 0.45, "y": 0.25, "thickness": 14}},
                           "text": [f"{e:.2f} mm to the {against}" for e in error] if len(error) <= 5000 else None,
                           "hoverinfo": "text" if len(error) <= 5000 else "skip",
                           "name": f"error: {label}", "visible": "legendonly"})

    if lesions:
        traces.append(_lesion_trace(lesions))
        meta["lesions"] = len(lesions)

    view_traces, frames, cones = _view_traces(views)
    offset = len(traces)
    traces.extend(view_traces)
    groups["views"] = [offset + i for i in frames]
    groups["cones"] = [offset + i for i in cones]
    meta["views"] = [view.name for view in views]
    for trace in traces:
        if trace.get("text") is None:
            trace.pop("text", None)
    return _Scene(traces, groups, meta)


def _buttons(groups: Mapping[str, list[int]]) -> list[dict]:
    buttons = []
    for key, label in (("views", "views"), ("cones", "X-ray cones"), ("truth", "truth &amp; error")):
        indices = groups.get(key) or []
        if indices:
            buttons.append({"label": label, "method": "restyle", "args": [{"visible": True}, indices],
                            "args2": [{"visible": "legendonly"}, indices]})
    if not buttons:
        return []
    return [{"type": "buttons", "direction": "right", "showactive": False, "x": 0.0, "xanchor": "left",
             "y": 1.0, "yanchor": "top", "pad": {"l": 4, "t": 4}, "buttons": buttons,
             "bgcolor": "#f2f2f2", "bordercolor": "#999999", "font": {"size": 12}}]


def viewer_html(*, vessel_points_mm: Any, mesh_vertices_mm: Any = None, mesh_faces: Any = None, tree: Any = None,
                centerline_points_mm: Any = None, views: Sequence[ViewerView] = (), ground_truth_mm: Any = None,
                ground_truth_tree: Any = None, lesions: Sequence[Mapping[str, Any]] = (), title: str = "angiohull",
                subtitle: str | Sequence[str] = "") -> str:
    """The viewer page of a reconstruction (one self-contained HTML document, UTF-8).

    Parameters
    ----------
    vessel_points_mm : array_like, shape (N, 3)
        The carved lumen points, mm (may be empty).
    mesh_vertices_mm, mesh_faces : array_like, shapes (V, 3) and (F, 3), optional
        The vessel's surface (e.g. :func:`angiohull.tree.solid.surface_mesh`); decimated above
        :data:`MAX_MESH_FACES` faces.
    tree : VesselTree, optional
        Drawn as centerlines coloured by radius.
    centerline_points_mm : array_like, shape (M, 3), optional
        Drawn when there is no tree.
    views : sequence of ViewerView
        The acquired views (source, detector, X-ray cone).
    ground_truth_mm : array_like, shape (T, 3), optional
        Truth points; with them (or a true tree) the error layers are added.
    ground_truth_tree : VesselTree, optional
        The true tree: drawn, and the reference of the centerline error.
    lesions : sequence of mapping
        Rows of a quantitative analysis (``QcaResult.lesion_rows()``, or qca.json's ``lesions``):
        ``x_mm, y_mm, z_mm, mld_mm, diameter_stenosis_pct, lesion_length_mm`` and optionally
        ``branch, branch_name, reference_diameter_mm, best_view``.
    title : str
        The page's heading (plain text).
    subtitle : str or sequence of str
        Lines under it (plain text), e.g. the scores.

    Raises
    ------
    ViewerError
        If an array has the wrong shape or non-finite values, a face indexes a missing vertex, a
        lesion row lacks a number, or plotly is not installed.
    """
    views = list(views)
    for i, view in enumerate(views):
        if not isinstance(view, ViewerView):
            raise ViewerError(f"views[{i}] must be a ViewerView, got {type(view).__name__}")
    scene = _scene(vessel_points_mm=vessel_points_mm, mesh_vertices_mm=mesh_vertices_mm, mesh_faces=mesh_faces,
                   tree=tree, centerline_points_mm=centerline_points_mm, views=views, ground_truth_mm=ground_truth_mm,
                   ground_truth_tree=ground_truth_tree, lesions=list(lesions))
    heading = {"text": _text(title), "x": 0.5, "xanchor": "center", "y": 0.99, "yanchor": "top", "yref": "container",
               "font": {"size": 15}}
    lines = [subtitle] if isinstance(subtitle, str) else [str(line) for line in subtitle]
    lines = [line for line in lines if line]
    if lines:
        heading["subtitle"] = {"text": "<br>".join(_text(line) for line in lines), "font": {"size": 11, "color": "#444444"}}
    axis = {"showbackground": True, "backgroundcolor": "#f7f7f7", "gridcolor": "#dddddd", "zeroline": False}
    layout = {
        "title": heading,
        "margin": {"l": 0, "r": 0, "t": 46 + 16 * len(lines), "b": 0},
        "paper_bgcolor": "white",
        "showlegend": True,
        "legend": {"x": 0.0, "xanchor": "left", "y": 0.93, "yanchor": "top", "bgcolor": "rgba(255,255,255,0.85)",
                   "bordercolor": "#cccccc", "borderwidth": 1, "font": {"size": 11}},
        "scene": {
            "domain": {"x": [0.17, 1.0], "y": [0.0, 1.0]},
            "aspectmode": "data",
            "xaxis": {**axis, "title": {"text": "x (mm): patient left →"}},
            "yaxis": {**axis, "title": {"text": "y (mm): posterior →"}},
            "zaxis": {**axis, "title": {"text": "z (mm): head ↑"}},
            # seen from the front (anterior), head up: the patient's left on the viewer's right
            "camera": {"eye": {"x": 0.0, "y": -1.9, "z": 0.25}, "up": {"x": 0, "y": 0, "z": 1},
                       "center": {"x": 0, "y": 0, "z": 0}, "projection": {"type": "perspective"}},
            "dragmode": "orbit",
        },
        "updatemenus": _buttons(scene.groups),
        "uirevision": "angiohull",
        "hoverlabel": {"align": "left"},
    }
    config = {"responsive": True, "displaylogo": False, "scrollZoom": True,
              "toImageButtonOptions": {"format": "png", "filename": "angiohull-viewer", "scale": 2}}
    figure = {"data": scene.traces, "layout": layout, "config": config,
              "angiohull": {"version": __version__, **scene.meta, "groups": scene.groups}}
    payload = json.dumps(figure, separators=(",", ":"), allow_nan=False).replace("</", "<\\/")
    page_title = html.escape(title)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        f"<meta name=\"generator\" content=\"angiohull {html.escape(__version__)}\">\n"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
        f"<title>{page_title}</title>\n"
        "<style>html,body{margin:0;height:100%;font-family:sans-serif;background:#fff}"
        "#angiohull-plot{position:absolute;top:0;left:0;right:0;bottom:0}"
        "#angiohull-help{position:absolute;left:6px;bottom:4px;font-size:11px;color:#666;pointer-events:none}</style>\n"
        f"<script>{plotly_js()}</script>\n"
        "</head>\n<body>\n<div id=\"angiohull-plot\"></div>\n"
        "<div id=\"angiohull-help\">drag: rotate · scroll: zoom · right-drag: pan · legend: click toggles a layer, "
        "double-click shows it alone · buttons: views, X-ray cones, truth</div>\n"
        f"<script type=\"application/json\" id=\"{FIGURE_ELEMENT_ID}\">{payload}</script>\n"
        "<script>\n(function () {\n"
        f"  var figure = JSON.parse(document.getElementById('{FIGURE_ELEMENT_ID}').textContent);\n"
        "  Plotly.newPlot('angiohull-plot', figure.data, figure.layout, figure.config).then(function () {\n"
        "    window.angiohullReady = true;\n  });\n})();\n</script>\n</body>\n</html>\n"
    )


def write_viewer(path: str | os.PathLike[str], **kwargs: Any) -> Path:
    """Write :func:`viewer_html` (``kwargs``) to ``path`` atomically (a temporary file in the same
    folder, then renamed) and return the path.

    Raises
    ------
    ViewerError
        As :func:`viewer_html`.
    OutputError
        If the file cannot be written (nothing is left behind).
    """
    text = viewer_html(**kwargs)
    out = Path(path)
    temporary = out.parent / f".{out.name}.{secrets.token_hex(6)}.partial"
    try:
        with open(temporary, "x", encoding="utf-8") as handle:  # created with the usual permissions
            handle.write(text)
        temporary.replace(out)
    except OSError as exc:
        temporary.unlink(missing_ok=True)
        raise OutputError(f"cannot write {out}: {exc.strerror or exc}") from None
    return out
