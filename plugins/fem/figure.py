"""The picture a ``simulate`` stage writes: the deformed tissue coloured by stress (PNG).

For a first look without ParaView: the final equilibrium's boundary surface
in 3D, each triangle coloured by the largest absolute principal second
Piola-Kirchhoff stress of its element (kPa, the paper's §IV-D measure; the
colour scale runs from 0 to the largest stress, square-root spaced so that
the peaks at the gripper's corners do not wash out the rest), the rest
shape as a grey outline, the anchored nodes black and the grasped ones red;
the colour bar in an axes of its own beside the 3D box (never over its
labels), each axis with as many ticks as its extent has room for; the
settings' probes (a displacement against a reference, e.g. a cantilever's
tip against the elastica) under the title; with quasi-static steps, a
second panel plots the energy Π and the largest stress against the fraction
of the motion applied. Lengths in mm. Written atomically.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from surgiplan.deformable import EquilibriumState

    from .model import StVKModel


def stage_figure(
    path: Path,
    model: StVKModel,
    state: EquilibriumState,
    title: str,
    steps: dict | None = None,
    notes: list[str] | None = None,
) -> Path:
    """Write ``path`` (PNG); ``steps``: per-step ``step_fraction``, ``step_energy_J``, ``step_max_stress_Pa``;
    ``notes``: lines under the title (the probes against their references)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker
    from matplotlib import cm
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection
    from surgiplan.storage import atomic_write

    mm = 1e3
    mesh = model.mesh
    triangles = mesh.surface
    x = state.positions * mm
    rest = mesh.nodes * mm
    stress = np.asarray(state.stress, dtype=float)[mesh.surface_elements] / 1e3  # kPa
    norm = stress_norm(stress)
    top = float(norm.vmax)
    cmap = matplotlib.colormaps["viridis"]

    wide = steps is not None and len(steps.get("step_fraction", [])) > 1
    fig = plt.figure(figsize=(13.5 if wide else 8.0, 5.6))
    # the 3D box, its colour bar, and (with steps) a spacer for the bar's ticks and the steps panel
    grid = fig.add_gridspec(
        1, 4 if wide else 2, width_ratios=[1.0, 0.035, 0.2, 0.85] if wide else [1.0, 0.04], wspace=0.12 if wide else 0.2
    )
    ax = fig.add_subplot(grid[0, 0], projection="3d")
    cax = fig.add_subplot(grid[0, 1])
    surface = Poly3DCollection(x[triangles], facecolors=cmap(norm(np.nan_to_num(stress, nan=0.0))), linewidths=0)
    ax.add_collection3d(surface)
    edges = _outline(mesh.nodes, mesh.surface)
    if len(edges):  # a smooth closed surface (a sphere) has no feature edge
        ax.add_collection3d(Line3DCollection(rest[edges], colors="0.6", linewidths=0.6))
    held = state.data.get("prescribed_nodes", np.empty(0, dtype=int))
    grasped = np.intersect1d(held, model.grasped_nodes())
    anchored = np.setdiff1d(held, grasped)
    if len(anchored):
        ax.scatter(*x[anchored].T, s=3, c="k", depthshade=False, label="anchored")
    if len(grasped):
        ax.scatter(*x[grasped].T, s=8, c="tab:red", depthshade=False, label="grasped")
    lower = np.minimum(x.min(axis=0), rest.min(axis=0))
    upper = np.maximum(x.max(axis=0), rest.max(axis=0))
    ax.set_xlim(lower[0], upper[0])
    ax.set_ylim(lower[1], upper[1])
    ax.set_zlim(lower[2], upper[2])
    extent = np.maximum(upper - lower, 1e-3 * (upper - lower).max())
    ax.set_box_aspect(extent)
    ax.view_init(elev=25, azim=-60)
    # ticks in proportion to each axis's drawn length (a 10 mm side of a 100 mm beam gets two, not five
    # overlapping ones), and labels pushed clear of them
    for axis, name, length in zip((ax.xaxis, ax.yaxis, ax.zaxis), "xyz", extent / extent.max(), strict=True):
        axis.set_major_locator(matplotlib.ticker.MaxNLocator(int(np.clip(round(6 * length), 1, 5)), min_n_ticks=2))
        axis.set_label_text(f"{name} (mm)")
        axis.labelpad = 6 + 6 * (1 - length)
    if len(held):
        ax.legend(loc="upper left", fontsize=7)
    bar = fig.colorbar(cm.ScalarMappable(norm=norm, cmap=cmap), cax=cax)
    bar.set_label(
        f"max |principal 2nd Piola-Kirchhoff stress| (kPa)\nsquare-root scale, 0 to the largest, {top:,.4g}", fontsize=8
    )
    bar.ax.tick_params(labelsize=8)
    if wide:
        axe = fig.add_subplot(grid[0, 3])
        fraction = np.asarray(steps["step_fraction"])
        axe.plot(fraction, np.asarray(steps["step_energy_J"]) * 1e3, "o-", color="tab:blue")
        axe.set_xlabel("fraction of the motion applied")
        axe.set_ylabel("energy Π (mJ)", color="tab:blue")
        axs = axe.twinx()
        axs.plot(fraction, np.asarray(steps["step_max_stress_Pa"]) / 1e3, "s--", color="tab:red")
        axs.set_ylabel("largest stress (kPa)", color="tab:red")
        axe.grid(True, alpha=0.3)
        axe.set_title("quasi-static steps", fontsize=9)
    fig.suptitle(title, fontsize=10)
    if notes:
        fig.text(0.5, 0.905, "\n".join(notes), ha="center", va="top", fontsize=9, color="0.15")
    fig.subplots_adjust(left=0.02, right=0.95 if wide else 0.9, bottom=0.1, top=0.86 if notes else 0.9)
    path = Path(path)
    with atomic_write(path) as handle:
        fig.savefig(handle, format="png", dpi=100)
    plt.close(fig)
    return path


def stress_norm(stress: np.ndarray):
    """The colour scale of stresses (kPa): 0 to the largest finite one, square-root spaced (the gripper's
    corners concentrate stress, and a linear scale to their peak would leave the rest of the flap one colour)."""
    from matplotlib import colors

    finite = np.asarray(stress, dtype=float)
    finite = finite[np.isfinite(finite)]
    top = float(finite.max()) if finite.size else 0.0
    return colors.PowerNorm(0.5, 0.0, top if top > 0 else 1.0)


def _outline(nodes: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Feature edges (k, 2) of a surface: edges whose two triangles meet at more than 25 degrees (a box: 12)."""
    corners = nodes[triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    owner = np.tile(np.arange(len(triangles)), 3)
    key = np.sort(edges, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, owner = key[order], owner[order]
    pair = np.flatnonzero(np.all(key[1:] == key[:-1], axis=1))  # each interior edge appears twice, adjacent
    bend = np.einsum("ij,ij->i", normals[owner[pair]], normals[owner[pair + 1]]) < 0.9  # bent by more than 25 degrees
    return key[pair[bend]]
