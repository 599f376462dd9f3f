"""The picture a ``simulate`` stage writes: the deformed tissue coloured by stress (PNG).

For a first look without ParaView: the final equilibrium's boundary surface
in 3D, each triangle coloured by the largest absolute principal second
Piola-Kirchhoff stress of its element (kPa, the paper's §IV-D measure;
the colour scale ends at the 98th percentile, so that the peaks at the
gripper's corners do not wash out the rest), the
rest shape as a grey outline, the anchored nodes black and the grasped ones
red; with quasi-static steps, a second panel plots the energy Π and the
largest stress against the fraction of the motion applied. Lengths in mm.
Written atomically.
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
) -> Path:
    """Write ``path`` (PNG); ``steps``: per-step ``step_fraction``, ``step_energy_J``, ``step_max_stress_Pa``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker
    from matplotlib import cm, colors
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection
    from surgiplan.storage import atomic_write

    mm = 1e3
    mesh = model.mesh
    triangles = mesh.surface
    x = state.positions * mm
    rest = mesh.nodes * mm
    stress = np.asarray(state.stress, dtype=float)[mesh.surface_elements] / 1e3  # kPa
    finite = stress[np.isfinite(stress)]
    # the gripper's corners concentrate stress: scale colours to the 98th percentile so the rest shows
    top = float(np.percentile(finite, 98)) if finite.size else 0.0
    norm = colors.Normalize(0.0, top if top > 0 else 1.0)
    cmap = matplotlib.colormaps["viridis"]

    wide = steps is not None and len(steps.get("step_fraction", [])) > 1
    fig = plt.figure(figsize=(12.5 if wide else 7.5, 5.4))
    ax = fig.add_subplot(1, 2 if wide else 1, 1, projection="3d")
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
    ax.set_box_aspect(np.maximum(upper - lower, 1e-3 * (upper - lower).max()))
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    ax.view_init(elev=25, azim=-60)
    ax.zaxis.set_major_locator(matplotlib.ticker.MaxNLocator(3))
    ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(5))
    ax.yaxis.set_major_locator(matplotlib.ticker.MaxNLocator(5))
    if len(held):
        ax.legend(loc="upper left", fontsize=7)
    bar = fig.colorbar(cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.6, pad=0.1, extend="max")
    bar.set_label("max |principal 2nd Piola-Kirchhoff stress| (kPa)", fontsize=8)
    if wide:
        axe = fig.add_subplot(1, 2, 2)
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
    fig.tight_layout()
    path = Path(path)
    with atomic_write(path) as handle:
        fig.savefig(handle, format="png", dpi=100)
    plt.close(fig)
    return path


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
