"""A replanning instance drawn like paper 001 Fig. 6: A -> B planned, a new goal C given on the way.

The first plan from A to B is drawn solid up to the position R where the new
goal arrived and dashed beyond (the part abandoned); the replanned path from
R to C is drawn in another colour. A 3D view and a top view, obstacles in
grey, lengths in the figure's unit. Written atomically as PNG.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from surgiplan.storage import atomic_write

FIRST, ABANDONED, REPLANNED, OBSTACLE = "#1f6fb4", "#9a9a9a", "#d95f02", "#9a9a9a"


def _length(points: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum()) if len(points) > 1 else 0.0


def replanning_figure(
    path: Path,
    scene,
    first: np.ndarray,
    travelled: np.ndarray,
    replanned: np.ndarray,
    labels: dict[str, np.ndarray],
    *,
    unit: str = "mm",
    unit_scale: float = 1e-3,
    title: str = "",
) -> None:
    """``first``: the plan A -> B; ``travelled``: its part up to R; ``replanned``: R -> C (all (n, 3) m).

    ``labels``: named points to mark (A, B, C, R).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    k = 1.0 / unit_scale
    meshes = [(o.name, o.to_trimesh()) for o in scene.obstacles]
    fig = plt.figure(figsize=(13, 5.4))
    ax3 = fig.add_subplot(1, 2, 1, projection="3d")
    ax2 = fig.add_subplot(1, 2, 2)
    for _, mesh in meshes:
        ax3.add_collection3d(
            Poly3DCollection(mesh.vertices[mesh.faces] * k, facecolor=OBSTACLE, edgecolor="none", alpha=0.3)
        )
        ax2.add_collection(
            PolyCollection(mesh.vertices[mesh.faces][:, :, :2] * k, facecolor=OBSTACLE, edgecolor="none", alpha=0.8)
        )
    rest = first[len(travelled) - 1 :] if len(travelled) else first
    pieces = [
        (travelled, FIRST, "-", f"A to R, travelled ({_length(travelled) * k:.1f} {unit})"),
        (
            np.vstack([travelled[-1:], rest[1:]]) if len(travelled) else rest,
            ABANDONED,
            "--",
            f"R to B, abandoned (plan A to B: {_length(first) * k:.1f} {unit})",
        ),
        (replanned, REPLANNED, "-", f"replanned, R to C ({_length(replanned) * k:.1f} {unit})"),
    ]
    for points, colour, style, label in pieces:
        if len(points) < 2:
            continue
        p = points * k
        ax3.plot(p[:, 0], p[:, 1], p[:, 2], style, color=colour, linewidth=2.2)
        ax2.plot(p[:, 0], p[:, 1], style, color=colour, linewidth=2.2, label=label)
    markers = {"A": ("o", "#2ca02c"), "B": ("s", "black"), "C": ("*", "#d62728"), "R": ("D", REPLANNED)}
    for name, point in labels.items():
        marker, colour = markers.get(name, ("o", "black"))
        q = np.asarray(point) * k
        ax3.scatter(*q, marker=marker, color=colour, s=50, depthshade=False)
        ax3.text(*q, f" {name}", fontsize=10)
        ax2.plot(q[0], q[1], marker, color=colour, markersize=9)
        ax2.annotate(f" {name}", q[:2], fontsize=11, fontweight="bold")
    lo, hi = scene.bounds_min * k, scene.bounds_max * k
    ax3.set_xlim(lo[0], hi[0])
    ax3.set_ylim(lo[1], hi[1])
    ax3.set_zlim(lo[2], hi[2])
    ax3.set_box_aspect(hi - lo)
    ax3.view_init(elev=30, azim=-62)
    for axis, name in zip("xyz", ("x", "y", "z"), strict=True):
        getattr(ax3, f"set_{axis}label")(f"{name} ({unit})")
    for name, mesh in meshes:
        ax2.annotate(name, mesh.vertices.mean(axis=0)[:2] * k, ha="center", va="center", fontsize=7, color="#333333")
    ax2.add_patch(plt.Rectangle(lo[:2], *(hi - lo)[:2], fill=False, edgecolor="black", linewidth=0.8))
    ax2.set_xlim(lo[0], hi[0])
    ax2.set_ylim(lo[1], hi[1])
    ax2.set_aspect("equal")
    ax2.set_xlabel(f"x ({unit})")
    ax2.set_ylabel(f"y ({unit})")
    ax2.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=3, fontsize=8, frameon=False)
    fig.suptitle(title or "replanning (paper 001 Fig. 6): plan A to B, new goal C at R", fontsize=11)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    with atomic_write(path, "wb") as handle:
        fig.savefig(handle, format="png", dpi=120)
    plt.close(fig)
