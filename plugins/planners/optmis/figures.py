"""The whole repository in one figure: every path faintly, a few highlighted, and where the paths run.

Left, a 3D view: all paths as faint lines (so that the bundles along the
obstacles' edges and over their tops show), the query's path and a few
others highlighted, the points of interest as dots. Right, a top view of
the path density: for each 1 mm cell, how many paths pass through it (log
scale), with the obstacles and points of interest on top. Written
atomically as PNG.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from surgiplan.storage import atomic_write

from .repository import Repository

OBSTACLE = "#9a9a9a"
HIGHLIGHT = ("#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e")


def paths_per_cell(
    points: np.ndarray, start: np.ndarray, lo: np.ndarray, cell: float, shape: tuple[int, int]
) -> np.ndarray:
    """How many paths pass through each top-view cell (each path counted once per cell, its motions sampled)."""
    counts = np.zeros(shape[0] * shape[1], dtype=np.int64)
    for k in range(len(start) - 1):
        p = points[start[k] : start[k + 1], :2]
        if len(p) < 2:
            continue
        steps = np.maximum(np.ceil(np.linalg.norm(np.diff(p, axis=0), axis=1) / (0.5 * cell)).astype(int), 1)
        t = np.concatenate([np.linspace(0, 1, n, endpoint=False) for n in steps])
        segment = np.repeat(np.arange(len(steps)), steps)
        dense = np.concatenate([p[segment] + t[:, None] * (p[segment + 1] - p[segment]), p[-1:]])
        ij = np.clip(((dense - lo) / cell).astype(int), 0, np.array(shape) - 1)
        counts[np.unique(ij[:, 0] * shape[1] + ij[:, 1])] += 1
    return counts.reshape(shape)


def repository_figure(
    path: Path,
    scene,
    repository: Repository,
    highlight: list[int],
    *,
    unit: str = "mm",
    unit_scale: float = 1e-3,
    title: str = "",
) -> None:
    """Draw ``repository`` over ``scene``; ``highlight``: path indices drawn in colour (the first is the query)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection
    from matplotlib.colors import LogNorm
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    k = 1.0 / unit_scale
    meshes = [(o.name, o.to_trimesh()) for o in scene.obstacles]
    lo, hi = scene.bounds_min * k, scene.bounds_max * k
    fig = plt.figure(figsize=(14, 6))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax2 = fig.add_subplot(1, 2, 2)

    for _, mesh in meshes:
        ax3.add_collection3d(
            Poly3DCollection(mesh.vertices[mesh.faces] * k, facecolor=OBSTACLE, edgecolor="none", alpha=0.18)
        )
    starts = repository.path_start
    lines = [repository.points[starts[i] : starts[i + 1]] * k for i in range(repository.n_paths)]
    ax3.add_collection3d(Line3DCollection(lines, colors="#303030", linewidths=0.3, alpha=0.06))
    names = repository.names
    for colour, index in zip(HIGHLIGHT, highlight, strict=False):
        p = lines[index]
        i, j = repository.pairs[index]
        label = f"{names[i]} to {names[j]} ({repository.length[index] * k:.1f} {unit})"
        ax3.plot(p[:, 0], p[:, 1], p[:, 2], color=colour, linewidth=2.0, label=label)
    pois = repository.pois * k
    ax3.scatter(pois[:, 0], pois[:, 1], pois[:, 2], s=6, color="black", depthshade=False, label="points of interest")
    ax3.set_xlim(lo[0], hi[0])
    ax3.set_ylim(lo[1], hi[1])
    ax3.set_zlim(lo[2], hi[2])
    ax3.set_box_aspect(hi - lo)
    ax3.view_init(elev=32, azim=-60)
    for axis in "xyz":
        getattr(ax3, f"set_{axis}label")(f"{axis} ({unit})")
    ax3.set_title(f"all {repository.n_paths:,} paths (faint), {min(len(highlight), len(HIGHLIGHT))} highlighted")
    ax3.legend(loc="upper center", bbox_to_anchor=(0.5, -0.02), ncol=2, fontsize=8, frameon=False)

    cell = 1.0  # in the figure's unit
    shape = (max(int(np.ceil((hi[0] - lo[0]) / cell)), 1), max(int(np.ceil((hi[1] - lo[1]) / cell)), 1))
    counts = paths_per_cell(repository.points[:, :2] * k, repository.path_start, lo[:2], cell, shape)
    image = ax2.imshow(
        np.ma.masked_equal(counts.T, 0),
        origin="lower",
        extent=(lo[0], lo[0] + shape[0] * cell, lo[1], lo[1] + shape[1] * cell),
        cmap="viridis",
        norm=LogNorm(vmin=1, vmax=max(int(counts.max()), 2)),
        interpolation="nearest",
    )
    from scipy.spatial import ConvexHull

    for _, mesh in meshes:  # outlines, so that the paths over the obstacles' tops show
        footprint = mesh.vertices[:, :2] * k
        hull = footprint[ConvexHull(footprint).vertices]
        ax2.add_collection(PolyCollection([hull], facecolor="none", edgecolor="#404040", linewidth=1.0))
    for name, mesh in meshes:
        ax2.annotate(name, mesh.vertices.mean(axis=0)[:2] * k, ha="center", va="center", fontsize=7, color="#222222")
    ax2.plot(pois[:, 0], pois[:, 1], ".", color="black", markersize=3)
    ax2.add_patch(plt.Rectangle(lo[:2], *(hi - lo)[:2], fill=False, edgecolor="black", linewidth=0.8))
    ax2.set_xlim(lo[0], hi[0])
    ax2.set_ylim(lo[1], hi[1])
    ax2.set_aspect("equal")
    ax2.set_xlabel(f"x ({unit})")
    ax2.set_ylabel(f"y ({unit})")
    ax2.set_title(f"top view: paths per {cell:g} {unit} cell, all heights")
    bar = fig.colorbar(image, ax=ax2, fraction=0.035, pad=0.02)
    bar.set_label("paths (log scale)")
    fig.suptitle(title, fontsize=11)
    fig.tight_layout(rect=(0, 0.02, 1, 0.97))
    with atomic_write(path, "wb") as handle:
        fig.savefig(handle, format="png", dpi=120)
    plt.close(fig)
