"""Files a retraction plan writes: the states along the trajectory and figures like the paper's Figs. 5-7.

* ``<stage>-states.npz`` — the trajectory: configurations ``q`` (M, 7),
  node ``positions`` (M, n, 3) m, ``energy`` (M,) J, ``max_stress`` (M,) Pa,
  element ``stress`` (M, elements) Pa, the mesh's ``rest`` nodes,
  ``elements`` and surface ``triangles``, ``waypoints`` (indices of the
  roadmap states), the area of interest's ``area_points`` and which are
  ``visible`` at the end;
* ``<stage>-retraction.png`` — (a) the grasp (every candidate marked, the
  chosen one red) on the flap at rest, (b)-(d) snapshots of the deformed
  flap along the trajectory with the gripper's path, its jaws, the
  obstacles, and A shaded by visibility (green visible, red hidden);
* ``<stage>-profile.png`` — energy and largest stress along the trajectory,
  the cost of each candidate grasp, and A seen from above at the end.

All written atomically.
"""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import PolyCollection
from matplotlib.colors import LogNorm
from mpl_toolkits.mplot3d.art3d import Poly3DCollection
from surgiplan.storage import atomic_write, save_bundle

from .grasp import pose_matrices

TISSUE = "#e8a0a0"


def face_owner(elements: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The element (t,) each boundary triangle belongs to."""
    faces = np.sort(np.asarray(elements)[:, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]].reshape(-1, 3), axis=1)
    keys = np.sort(np.asarray(triangles), axis=1)
    width = int(max(faces.max(), keys.max())) + 1
    code = (faces[:, 0] * width + faces[:, 1]) * width + faces[:, 2]
    want = (keys[:, 0] * width + keys[:, 1]) * width + keys[:, 2]
    order = np.argsort(code, kind="stable")
    found = order[np.searchsorted(code[order], want)]
    return found // 4


def _stage_name(setup) -> str:
    workdir = setup.problem.workdir
    return workdir.name if workdir is not None else "retraction"


def write_outputs(setup, roadmaps, outcome, metrics) -> list[str]:
    out = Path(setup.problem.output_dir)
    name = _stage_name(setup)
    t = outcome.trajectory
    files = [f"{name}-states.npz"]
    if setup.settings.figures:
        files += [f"{name}-retraction.png", f"{name}-profile.png"]
    save_bundle(
        out / files[0],
        {
            "q": t.q,
            "positions": t.positions,
            "energy": t.energy,
            "max_stress": t.max_stress,
            "stress": t.stress,
            "rest": setup.rest,
            "elements": setup.elements,
            "triangles": setup.triangles,
            "waypoints": t.waypoints,
            "area_points": setup.visibility.points,
            "visible": t.visible,
        },
        {"units": "SI (m, J, Pa)", "metric": setup.settings.metric, "grasp": int(outcome.best)},
    )
    if setup.settings.figures:
        snapshots_figure(out / files[1], setup, roadmaps, outcome, metrics, name)
        profile_figure(out / files[2], setup, roadmaps, outcome, metrics, name)
    return files


def _save(fig, path: Path) -> None:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    with atomic_write(path) as handle:
        handle.write(buffer.getvalue())


def _draw_flap(ax, setup, positions, stress, owner, norm, k):
    tri = positions[setup.triangles] * k
    colours = plt.cm.viridis(norm(np.clip(stress[owner], norm.vmin, norm.vmax)))
    ax.add_collection3d(Poly3DCollection(tri, facecolors=colours, edgecolors="none", linewidths=0, alpha=0.95))


def _draw_obstacles(ax, scene, k):
    for obstacle in scene.obstacles:
        mesh = obstacle.to_trimesh()
        ax.add_collection3d(
            Poly3DCollection(
                np.asarray(mesh.vertices)[mesh.faces] * k, facecolors="#9a9a9a", edgecolors="none", alpha=0.25
            )
        )


def _draw_area(ax, points, visible, k):
    ax.scatter(*(points[visible].T * k), s=4, color="#2ca02c", depthshade=False)
    ax.scatter(*(points[~visible].T * k), s=4, color="#d62728", depthshade=False)


def _draw_jaws(ax, setup, q, k):
    jaws = setup.settings.jaws
    half = 0.5 * np.asarray(jaws.size)
    corners = np.array(np.meshgrid(*zip(-half, half, strict=True))).reshape(3, -1).T + np.asarray(jaws.offset)
    pose = pose_matrices(q)
    world = corners @ pose[:3, :3].T + pose[:3, 3]
    edges = [(a, b) for a in range(8) for b in range(a + 1, 8) if np.sum(corners[a] != corners[b]) == 1]
    for a, b in edges:
        ax.plot(*(world[[a, b]].T * k), color="black", linewidth=1.2)


def snapshots_figure(path: Path, setup, roadmaps, outcome, metrics, name: str) -> None:
    t = outcome.trajectory
    k = 1e3  # figures in mm
    owner = face_owner(setup.elements, setup.triangles)
    positive = t.stress[t.stress > 0]
    vmin = float(np.percentile(positive, 5)) if len(positive) else 1.0
    norm = LogNorm(vmin=max(vmin, 1.0), vmax=max(float(t.stress.max()), 10.0 * max(vmin, 1.0)))
    picks = np.unique(np.round(np.linspace(0, len(t.q) - 1, 4)).astype(int))
    lo = np.min(t.positions.reshape(-1, 3), axis=0)
    hi = np.max(t.positions.reshape(-1, 3), axis=0)
    lo = np.minimum(lo, t.q[:, :3].min(axis=0))
    hi = np.maximum(hi, t.q[:, :3].max(axis=0))
    for o in setup.problem.scene.obstacles:
        a, b = o.aabb()
        lo, hi = np.minimum(lo, a), np.maximum(hi, b)
    fig = plt.figure(figsize=(12, 10))
    labels = "abcd"
    for panel, index in enumerate(picks):
        ax = fig.add_subplot(2, 2, panel + 1, projection="3d")
        positions = t.positions[index].astype(float)
        _draw_flap(ax, setup, positions, t.stress[index].astype(float), owner, norm, k)
        _draw_obstacles(ax, setup.problem.scene, k)
        visible = setup.visibility.visible(positions, setup.triangles, pose_matrices(t.q[index]))
        _draw_area(ax, setup.visibility.points, visible, k)
        ax.plot(*(t.q[: index + 1, :3].T * k), color="#d62728", linewidth=1.5)
        _draw_jaws(ax, setup, t.q[index], k)
        if panel == 0:
            for g, roadmap in enumerate(roadmaps):
                chosen = g == outcome.best
                ax.scatter(
                    *(roadmap.grasp[:3] * k),
                    s=60 if chosen else 25,
                    color="#d62728" if chosen else "#555555",
                    marker="o",
                    depthshade=False,
                )
        ax.set_xlim(lo[0] * k, hi[0] * k)
        ax.set_ylim(lo[1] * k, hi[1] * k)
        ax.set_zlim(lo[2] * k, hi[2] * k)
        ax.set_box_aspect(np.maximum(hi - lo, 1e-6))
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.set_zlabel("z (mm)")
        ax.view_init(elev=28, azim=-60)
        ax.set_title(
            f"({labels[panel]}) state {index} of {len(t.q) - 1}: energy {t.energy[index] * 1e3:.3g} mJ, "
            f"visible {visible.mean():.0%}",
            fontsize=9,
        )
    mappable = plt.cm.ScalarMappable(norm=norm, cmap="viridis")
    fig.colorbar(mappable, ax=fig.axes, shrink=0.5, label="largest principal stress (Pa)")
    fig.suptitle(
        f"{name}: {setup.settings.metric} {metrics['cost']:.4g}, grasp {outcome.best} "
        f"({', '.join(f'{c * k:.3g}' for c in t.q[0, :3])}) mm, max energy {metrics['max_energy_J'] * 1e3:.3g} mJ, "
        f"max stress {metrics['max_stress_Pa'] / 1e3:.4g} kPa, A visible {metrics['visible_fraction']:.0%}",
        fontsize=10,
    )
    _save(fig, path)


def profile_figure(path: Path, setup, roadmaps, outcome, metrics, name: str) -> None:
    t = outcome.trajectory
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    ax = axes[0]
    ax.plot(t.energy * 1e3, color="#1f6fb4", label="energy Π (mJ)")
    ax.set_xlabel("trajectory state")
    ax.set_ylabel("energy (mJ)", color="#1f6fb4")
    for w in t.waypoints:
        ax.axvline(w, color="#cccccc", linewidth=0.6)
    twin = ax.twinx()
    twin.plot(t.max_stress / 1e3, color="#d62728")
    twin.set_ylabel("largest stress (kPa)", color="#d62728")
    ax.set_title("along the trajectory (grey: roadmap states)", fontsize=9)
    ax = axes[1]
    costs = [c["cost"] if c["cost"] is not None else np.nan for c in metrics["grasp_candidates"]]
    colours = ["#d62728" if i == outcome.best else "#888888" for i in range(len(costs))]
    ax.bar(np.arange(len(costs)), np.nan_to_num(costs, nan=0.0), color=colours)
    for i, c in enumerate(costs):
        if not np.isfinite(c):
            ax.text(i, 0, "no plan", rotation=90, ha="center", va="bottom", fontsize=8)
    ax.set_xticks(np.arange(len(costs)))
    ax.set_xlabel("grasp candidate")
    ax.set_ylabel(setup.settings.metric)
    ax.set_title("cost of each initial grasp (red: chosen)", fontsize=9)
    ax = axes[2]
    k = 1e3
    points = setup.visibility.points
    surface = t.positions[-1].astype(float)[setup.triangles]
    ax.add_collection(PolyCollection(surface[:, :, :2] * k, facecolors=TISSUE, edgecolors="none", alpha=0.15))
    ax.scatter(*(points[t.visible, :2].T * k), s=5, color="#2ca02c", label="visible")
    ax.scatter(*(points[~t.visible, :2].T * k), s=5, color="#d62728", label="hidden")
    polygon = np.asarray(setup.settings.visibility.area) * k
    ax.plot(*np.vstack([polygon, polygon[:1]]).T, color="black", linewidth=1)
    for o in setup.problem.scene.obstacles:
        a, b = o.aabb()
        ax.add_patch(plt.Rectangle(a[:2] * k, *(b - a)[:2] * k, color="#9a9a9a", alpha=0.4))
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.legend(fontsize=8, loc="upper right")
    ax.set_title(f"area of interest at the end: {np.mean(t.visible):.0%} visible (top view)", fontsize=9)
    fig.suptitle(name, fontsize=10)
    fig.tight_layout()
    _save(fig, path)
