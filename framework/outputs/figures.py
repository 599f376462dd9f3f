"""Figures in the style of the papers: obstacles, the path, its low-clearance parts.

Paper 000 Fig. 4 shows each proficiency level's path through the block world
in 3D, with the stretches that pass close to obstacles marked. Every plan
stage gets such a figure (a 3D view and a top view); a pipeline with several
plan stages also gets ``overview.png`` with one 3D panel per stage.
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
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

from ..scene import Scene
from ..storage import atomic_write

SAFE_COLOUR = "#1f6fb4"
LOW_COLOUR = "#d62728"
OBSTACLE_COLOUR = "#9a9a9a"


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

    def low_mask(self) -> np.ndarray:
        """Per segment: below the threshold (or in contact when there is none)."""
        limit = self.threshold if self.threshold is not None else 0.0
        c = np.minimum(self.clearance[:-1], self.clearance[1:])
        return c < limit if limit > 0 else c <= 0


def _scale(unit_scale: float) -> float:
    return 1.0 / unit_scale


def _obstacle_meshes(scene: Scene):
    return [(o.name, o.to_trimesh()) for o in scene.obstacles]


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
    for _, whole in meshes:
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
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(nbins=5))
    stretch = [f", stretched x{a / e:.3g}" if a / e > 1.01 else "" for a, e in zip(aspect, extent, strict=True)]
    ax.set_xlabel(f"x ({unit}){stretch[0]}")
    ax.set_ylabel(f"y ({unit}){stretch[1]}")
    ax.set_zlabel(f"z ({unit}){stretch[2]}")
    ax.view_init(elev=28, azim=-60)


def _draw_top(ax, scene: Scene, view: PathView, unit: str, k: float, meshes) -> None:
    for _, mesh in meshes:
        triangles = mesh.vertices[mesh.faces][:, :, :2] * k
        ax.add_collection(PolyCollection(triangles, facecolor=OBSTACLE_COLOUR, edgecolor="none", alpha=0.8))
    lo, hi = scene.bounds_min * k, scene.bounds_max * k
    ax.add_patch(plt.Rectangle(lo[:2], *(hi - lo)[:2], fill=False, edgecolor="black", linewidth=0.8))
    tips = view.tips[:, :2] * k
    segments = np.stack([tips[:-1], tips[1:]], axis=1)
    low = view.low_mask()
    ax.add_collection(LineCollection(segments[~low], colors=SAFE_COLOUR, linewidths=2.2, label="path"))
    if np.any(low):
        label = "below threshold" if view.threshold else "in contact"
        ax.add_collection(LineCollection(segments[low], colors=LOW_COLOUR, linewidths=2.8, label=label))
    if view.highlights:
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(view.tips, axis=0), axis=1))])
        for i, (a, b) in enumerate(view.highlights):
            inside = (arc >= a - 1e-12) & (arc <= b + 1e-12)
            if np.any(inside):
                pts = tips[inside]
                ax.plot(
                    pts[:, 0],
                    pts[:, 1],
                    color="orange",
                    linewidth=9,
                    alpha=0.35,
                    solid_capstyle="round",
                    label="critical region" if i == 0 else None,
                )
    if view.start is not None:
        ax.plot(*(view.start[:2] * k), "o", color="#2ca02c", label="start")
    if view.goal is not None:
        ax.plot(*(view.goal[:2] * k), "*", color="black", markersize=11, label="goal")
    for name, mesh in meshes:
        centre = mesh.vertices.mean(axis=0)[:2] * k
        ax.annotate(name, centre, ha="center", va="center", fontsize=7, color="#333333")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel(f"x ({unit})")
    ax.set_ylabel(f"y ({unit})")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=5, fontsize=7, frameon=False)


def plan_figure(path: Path, scene: Scene, view: PathView, *, unit: str, unit_scale: float) -> None:
    """One plan stage: 3D view and top view, written atomically as PNG."""
    k = _scale(unit_scale)
    meshes = _obstacle_meshes(scene)
    fig = plt.figure(figsize=(13, 5.2))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    _draw_3d(ax3, scene, [view], unit, k, meshes)
    ax2 = fig.add_subplot(1, 2, 2)
    _draw_top(ax2, scene, view, unit, k, meshes)
    fig.suptitle(view.title or view.label, fontsize=11)
    fig.tight_layout()
    _save(fig, path)


def overview_figure(
    path: Path, panels: Sequence[tuple[Scene, PathView]], *, unit: str, unit_scale: float, title: str = ""
) -> None:
    """Several plan stages side by side, one 3D panel each (like paper 000 Fig. 4)."""
    k = _scale(unit_scale)
    n = len(panels)
    cols = min(n, 2) if n <= 4 else 3
    rows = int(np.ceil(n / cols))
    fig = plt.figure(figsize=(6.2 * cols, 4.6 * rows))
    for i, (scene, view) in enumerate(panels):
        ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
        _draw_3d(ax, scene, [view], unit, k, _obstacle_meshes(scene))
        panel = textwrap.fill(f"({chr(ord('a') + i)}) {view.title or view.label}", width=60)
        ax.set_title(panel, fontsize=9)
    if title:
        fig.suptitle(title, fontsize=12)
    fig.tight_layout()
    _save(fig, path)


def _save(fig, path: Path) -> None:
    try:
        with atomic_write(path, "wb") as handle:
            fig.savefig(handle, format="png", dpi=110)
    finally:
        plt.close(fig)
