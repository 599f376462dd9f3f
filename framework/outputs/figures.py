"""Figures in the style of the papers: obstacles, the path, its low-clearance parts.

Paper 000 Fig. 4 shows each proficiency level's path through the block world
in 3D, the critical regions circled by solid ovals and the passages a detour
avoided by dashed ones. Every plan stage gets such a figure (a 3D view and a
top view, where a stretch that passes *over* an obstacle is marked with its
height); a pipeline with several plan stages also gets ``overview.png`` with
one 3D panel per stage. Every figure has a legend.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

from ..scene import Scene
from ..storage import atomic_write
from .merged import MAX_SEPARATE, drawn_meshes, group_of

SAFE_COLOUR = "#1f6fb4"
LOW_COLOUR = "#d62728"
OBSTACLE_COLOUR = "#9a9a9a"
CRITICAL_COLOUR = "#e67e00"
DETOUR_COLOUR = "#6a3d9a"


@dataclass
class PathView:
    """A path ready to draw: dense tip positions and the body's clearance at each."""

    label: str
    tips: np.ndarray  # (n, 3) m
    clearance: np.ndarray  # (n,) m
    threshold: float | None
    start: np.ndarray | None = None
    goal: np.ndarray | None = None
    title: str = ""
    #: [(start_m, end_m)] arc-length intervals to highlight (critical regions)
    highlights: Sequence[tuple[float, float]] = ()
    #: tip positions (k, 3) m of each passage a detour avoided (planner annotation ``detours``)
    detours: Sequence[np.ndarray] = ()

    def arc(self) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.tips, axis=0), axis=1))])

    def critical_points(self) -> list[np.ndarray]:
        """Tip positions of each critical region."""
        arc = self.arc()
        out = []
        for a, b in self.highlights:
            inside = (arc >= a - 1e-12) & (arc <= b + 1e-12)
            if np.any(inside):
                out.append(self.tips[inside])
        return out

    def low_mask(self) -> np.ndarray:
        """Per segment: below the threshold (or in contact when there is none)."""
        limit = self.threshold if self.threshold is not None else 0.0
        c = np.minimum(self.clearance[:-1], self.clearance[1:])
        return c < limit if limit > 0 else c <= 0


#: stretches over obstacles labelled in the top view at most (more are dashed only)
_MAX_OVER_LABELS = 6
_ELEVATION, _AZIMUTH = 28.0, -60.0
#: from the scene towards the 3D view's camera (matplotlib's elevation and azimuth, in degrees)
_VIEW_TOWARDS_CAMERA = np.array(
    [
        np.cos(np.radians(_ELEVATION)) * np.cos(np.radians(_AZIMUTH)),
        np.cos(np.radians(_ELEVATION)) * np.sin(np.radians(_AZIMUTH)),
        np.sin(np.radians(_ELEVATION)),
    ]
)


def _scale(unit_scale: float) -> float:
    return 1.0 / unit_scale


def _obstacle_meshes(scene: Scene):
    """(name, obstacles held, trimesh) of what is drawn: one an obstacle, or one merged mesh a group (merged.py);
    a merged mesh's boxes are drawn as quadrilaterals (``_polygons``)."""
    import trimesh

    out = []
    for d in drawn_meshes(scene.obstacles):
        mesh = trimesh.Trimesh(d.vertices, d.faces, process=False)
        mesh.metadata["quads"], mesh.metadata["quad_triangles"] = d.quads, d.quad_triangles
        out.append((d.name, d.count, mesh))
    return out


def _polygons(mesh, keep) -> list[np.ndarray]:
    """A merged mesh's faces as polygons (m), those whose outward normal ``keep`` accepts: its boxes' quadrilaterals
    (one polygon a box face instead of two triangles: the same pixels) and its other shapes' triangles."""
    quads = mesh.metadata.get("quads")
    first = mesh.metadata.get("quad_triangles", 0)
    faces = mesh.faces[first:]
    out = [mesh.vertices[faces[keep(mesh.face_normals[first:])]]]
    if quads is not None and len(quads):
        corners = mesh.vertices[quads]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        out.insert(0, corners[keep(normals)])
    return out


def _oval(points: np.ndarray, k: float, pad: float, n: int = 72) -> np.ndarray:
    """A horizontal ellipse (n, 3) around points (k, 3) m, in figure units: the region's footprint plus pad."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)[:2] + pad
    angle = np.linspace(0.0, 2 * np.pi, n)
    ring = np.column_stack(
        [centre[0] + half[0] * np.cos(angle), centre[1] + half[1] * np.sin(angle), np.full(n, centre[2])]
    )
    return ring * k


def _pad(scene: Scene) -> float:
    return 0.04 * float(np.min(scene.extent[:2]))


def _inside(mesh, lo: np.ndarray, hi: np.ndarray):
    """The part of an obstacle's surface inside the workspace box (3D axes do not clip what overflows them);
    cut open where it crosses the box, which is where the box's own edges are drawn."""
    for axis in range(3):
        for bound, sign in ((lo[axis], 1.0), (hi[axis], -1.0)):
            if np.all(sign * (mesh.vertices[:, axis] - bound) >= 0):
                continue  # wholly on the inner side of this face
            normal = np.zeros(3)
            normal[axis] = sign
            origin = np.zeros(3)
            origin[axis] = bound
            mesh = mesh.slice_plane(origin, normal)
            if mesh is None or not len(mesh.faces):
                return None
    return mesh


def _draw_3d(ax, scene: Scene, views: Sequence[PathView], unit: str, k: float, meshes) -> None:
    for _, count, whole in meshes:
        if count > 1 and np.all(whole.vertices >= scene.bounds_min) and np.all(whole.vertices <= scene.bounds_max):
            # a merged mesh of many obstacles: the faces turned away from the camera are left out (half of them;
            # what they add is a darker tint behind the front faces, not a shape)
            for polygons in _polygons(whole, lambda n: n @ _VIEW_TOWARDS_CAMERA > 0):
                if len(polygons):
                    collection = Poly3DCollection(polygons * k, facecolor=OBSTACLE_COLOUR, edgecolor="none", alpha=0.35)
                    ax.add_collection3d(collection)
            continue
        mesh = _inside(whole, scene.bounds_min, scene.bounds_max)
        if mesh is None:
            continue
        triangles = mesh.vertices[mesh.faces] * k
        collection = Poly3DCollection(triangles, facecolor=OBSTACLE_COLOUR, edgecolor="none", alpha=0.35)
        ax.add_collection3d(collection)
    for view in views:
        tips = view.tips * k
        segments = np.stack([tips[:-1], tips[1:]], axis=1)
        low = view.low_mask()
        colours = np.where(low[:, None], np.array([[0.84, 0.15, 0.16, 1.0]]), np.array([[0.12, 0.44, 0.71, 1.0]]))
        ax.add_collection3d(Line3DCollection(segments, colors=colours, linewidths=2.2))
        for points in view.critical_points():
            ring = _oval(points, k, _pad(scene))
            ax.plot(*ring.T, color=CRITICAL_COLOUR, linewidth=1.6, linestyle="-")
        for points in view.detours:
            ring = _oval(np.asarray(points), k, _pad(scene))
            ax.plot(*ring.T, color=DETOUR_COLOUR, linewidth=1.4, linestyle="--")
        if view.start is not None:
            ax.scatter(*(view.start * k), color="#2ca02c", s=30, depthshade=False)
        if view.goal is not None:
            ax.scatter(*(view.goal * k), color="black", marker="*", s=60, depthshade=False)
    lo, hi = scene.bounds_min * k, scene.bounds_max * k
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    # a thin axis (a 1 m layer of a 24 m hall) is drawn at least a quarter of the longest, so that its tick
    # labels do not pile up; the label says by how much it is stretched
    extent = np.maximum(hi - lo, 1e-12)
    aspect = np.maximum(extent, extent.max() / 4)
    ax.set_box_aspect(aspect.copy())  # (matplotlib scales the array it is given in place)
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(MaxNLocator(nbins=5))
    # a flat box leaves little room for z ticks: few of them, so the labels never overlap
    flatness = float(aspect[2] / max(aspect[0], aspect[1]))
    ax.zaxis.set_major_locator(MaxNLocator(nbins=int(np.clip(round(8 * flatness), 2, 5))))
    stretch = [f", stretched x{a / e:.3g}" if a / e > 1.01 else "" for a, e in zip(aspect, extent, strict=True)]
    ax.set_xlabel(f"x ({unit}){stretch[0]}")
    ax.set_ylabel(f"y ({unit}){stretch[1]}")
    ax.set_zlabel(f"z ({unit}){stretch[2]}", labelpad=2)
    ax.view_init(elev=_ELEVATION, azim=_AZIMUTH)


def _over_obstacles(scene: Scene, tips: np.ndarray) -> list[tuple[int, int, str, float]]:
    """Stretches [i0, i1] of the tip path that pass over an obstacle: (i0, i1, obstacle name, mean height m).

    A tip is over an obstacle when a point straight below it (sampled down to the floor) is inside one.
    """
    if not scene.obstacles or len(tips) < 2:
        return []
    floor = scene.bounds_min[2]
    heights = np.linspace(0.0, 1.0, 12)[:-1]
    column = tips[:, None, :].repeat(len(heights), axis=1)
    column[:, :, 2] = floor + heights[None, :] * (tips[:, 2:3] - floor)
    distance, index = scene.signed_distance(column.reshape(-1, 3))
    inside = (distance < 0).reshape(len(tips), -1)
    owner = np.where(inside, index.reshape(len(tips), -1), -1).max(axis=1)
    # many obstacles are drawn merged (merged.py): a stretch is named by the group it passes over
    name = (lambda o: o.name) if len(scene.obstacles) <= MAX_SEPARATE else group_of
    names = [None if o < 0 else name(scene.obstacles[int(o)]) for o in owner]
    out = []
    i = 0
    while i < len(tips):
        if names[i] is None:
            i += 1
            continue
        j = i
        while j + 1 < len(tips) and names[j + 1] == names[i]:
            j += 1
        out.append((i, j, names[i], float(tips[i : j + 1, 2].mean())))
        i = j + 1
    return out


def _draw_top(ax, scene: Scene, view: PathView, unit: str, k: float, meshes) -> None:
    for _, count, mesh in meshes:
        if count > 1:
            # a closed surface's footprint is its upward faces' (a vertical line enters through a downward face
            # and leaves through an upward one): a box's top face instead of its 12 triangles, the same pixels
            for polygons in _polygons(mesh, lambda n: n[:, 2] > 1e-12):
                ax.add_collection(
                    PolyCollection(polygons[:, :, :2] * k, facecolor=OBSTACLE_COLOUR, edgecolor="none", alpha=0.8)
                )
            continue
        triangles = mesh.vertices[mesh.faces][:, :, :2] * k
        ax.add_collection(PolyCollection(triangles, facecolor=OBSTACLE_COLOUR, edgecolor="none", alpha=0.8))
    lo, hi = scene.bounds_min * k, scene.bounds_max * k
    ax.add_patch(plt.Rectangle(lo[:2], *(hi - lo)[:2], fill=False, edgecolor="black", linewidth=0.8))
    tips = view.tips[:, :2] * k
    segments = np.stack([tips[:-1], tips[1:]], axis=1)
    low = view.low_mask()
    # round caps: a dense path's many short segments would otherwise show seams at every joint
    ax.add_collection(LineCollection(segments[~low], colors=SAFE_COLOUR, linewidths=2.2, capstyle="round"))
    if np.any(low):
        ax.add_collection(LineCollection(segments[low], colors=LOW_COLOUR, linewidths=2.8, capstyle="round"))
    for points in view.critical_points():
        ring = _oval(points, k, _pad(scene))
        ax.plot(ring[:, 0], ring[:, 1], color=CRITICAL_COLOUR, linewidth=1.6)
    for points in view.detours:
        ring = _oval(np.asarray(points), k, _pad(scene))
        ax.plot(ring[:, 0], ring[:, 1], color=DETOUR_COLOUR, linewidth=1.4, linestyle="--")
    for name, count, mesh in meshes:
        if count > 1:
            continue  # a merged group: its name is in the legend, not on thousands of boxes
        centre = mesh.vertices.mean(axis=0)[:2] * k
        ax.annotate(name, centre, ha="center", va="center", fontsize=7, color="#333333")
    # the top view hides height: mark where the path passes over an obstacle, and how high
    over = _over_obstacles(scene, view.tips)
    for i0, i1, name, z in over:
        stretch = tips[i0 : i1 + 1]
        ax.plot(stretch[:, 0], stretch[:, 1], color="white", linewidth=1.0, linestyle=(0, (2, 2)))
        if len(over) > _MAX_OVER_LABELS:
            continue  # a path across a field of voxels: the dashes (and the legend) say it, labels would pile up
        middle = stretch[len(stretch) // 2]
        ax.annotate(
            f"over {name}, z {z * k:.3g} {unit}",
            middle,
            xytext=(0, 9),
            textcoords="offset points",
            ha="center",
            fontsize=7,
            color="#222222",
            bbox={"boxstyle": "round,pad=0.15", "facecolor": "white", "alpha": 0.8, "edgecolor": "none"},
        )
    if view.start is not None:
        ax.plot(*(view.start[:2] * k), "o", color="#2ca02c")
    if view.goal is not None:
        ax.plot(*(view.goal[:2] * k), "*", color="black", markersize=11)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel(f"x ({unit})")
    ax.set_ylabel(f"y ({unit})")


def _legend(fig, scene: Scene, views: Sequence[PathView], unit: str, k: float, top_view: bool = True) -> None:
    """One legend for the figure, listing only what is drawn."""
    handles = [
        Line2D([], [], color=SAFE_COLOUR, linewidth=2.2, label="path"),
        Line2D([], [], marker="o", color="#2ca02c", linestyle="none", label="start"),
        Line2D([], [], marker="*", color="black", markersize=10, linestyle="none", label="goal"),
        Patch(facecolor=OBSTACLE_COLOUR, alpha=0.6, label="obstacle"),
    ]
    thresholds = {v.threshold for v in views if v.threshold}
    if any(np.any(v.low_mask()) for v in views):
        label = "below the clearance threshold" if thresholds else "in contact"
        if len(thresholds) == 1:
            label = f"clearance below {next(iter(thresholds)) * k:.3g} {unit}"
        handles.append(Line2D([], [], color=LOW_COLOUR, linewidth=2.8, label=label))
    if any(v.critical_points() for v in views):
        handles.append(Line2D([], [], color=CRITICAL_COLOUR, linewidth=1.6, label="critical region (no safe detour)"))
    if any(len(v.detours) for v in views):
        handles.append(Line2D([], [], color=DETOUR_COLOUR, linewidth=1.4, linestyle="--", label="avoided by a detour"))
    if top_view and any(_over_obstacles(scene, v.tips) for v in views):
        handles.append(Line2D([], [], color="#555555", linestyle=(0, (2, 2)), label="passes over an obstacle"))
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 4), fontsize=8, frameon=False)


def plan_figure(path: Path, scene: Scene, view: PathView, *, unit: str, unit_scale: float) -> None:
    """One plan stage: 3D view and top view, written atomically as PNG."""
    k = _scale(unit_scale)
    meshes = _obstacle_meshes(scene)
    fig = plt.figure(figsize=(13, 5.8))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    _draw_3d(ax3, scene, [view], unit, k, meshes)
    ax2 = fig.add_subplot(1, 2, 2)
    _draw_top(ax2, scene, view, unit, k, meshes)
    fig.suptitle(view.title or view.label, fontsize=11)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    _legend(fig, scene, [view], unit, k)
    save_figure(fig, path)


def overview_figure(
    path: Path, panels: Sequence[tuple[Scene, PathView]], *, unit: str, unit_scale: float, title: str = ""
) -> None:
    """Several plan stages side by side, one 3D panel each (like paper 000 Fig. 4)."""
    k = _scale(unit_scale)
    n = len(panels)
    cols = min(n, 2) if n <= 4 else 3
    rows = int(np.ceil(n / cols))
    fig = plt.figure(figsize=(6.2 * cols, 4.6 * rows + 0.6))
    for i, (scene, view) in enumerate(panels):
        ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
        _draw_3d(ax, scene, [view], unit, k, _obstacle_meshes(scene))
        panel = textwrap.fill(f"({chr(ord('a') + i)}) {view.title or view.label}", width=60)
        ax.set_title(panel, fontsize=9)
    if title:
        fig.suptitle(title, fontsize=12)
    fig.tight_layout(rect=(0, 0.6 / (4.6 * rows + 0.6), 1, 1))
    _legend(fig, panels[0][0], [v for _, v in panels], unit, k, top_view=False)
    save_figure(fig, path)


def save_figure(fig, path: Path) -> None:
    """Write ``fig`` to ``path`` as a PNG (110 dpi) atomically, and close it."""
    try:
        with atomic_write(path, "wb") as handle:
            fig.savefig(handle, format="png", dpi=110)
    finally:
        plt.close(fig)
