"""What the report draws of tissue: a simulate stage's ``.pvd``/``.vtu`` sequence and a retraction plan's
``<stage>-states.npz``, coloured by the largest principal stress.

A ``.vtu`` may hold any volume cells meshio reads: tetrahedra, hexahedra, wedges and pyramids, linear or
quadratic (a quadratic cell is drawn by its corners). The page draws the boundary: every cell face
(triangles and quadrilaterals, turned outward) that no other cell shares, a quadrilateral as two
triangles, each triangle coloured by its cell's stress."""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ...storage import load_bundle
from .packing import MAX_FRAMES, Notes, inside, pack

#: per volume cell type (meshio's names): corner count, and its faces by local corner index
_CELL_FACES: dict[str, tuple[int, list[list[int]]]] = {
    "tetra": (4, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]),
    "pyramid": (5, [[0, 3, 2, 1], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]),
    "wedge": (6, [[0, 2, 1], [3, 4, 5], [0, 1, 4, 3], [1, 2, 5, 4], [2, 0, 3, 5]]),
    "hexahedron": (8, [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]),
}
#: quadratic cells: drawn by their corners (the first nodes, as VTK orders them)
_QUADRATIC = {
    "tetra10": "tetra",
    "pyramid13": "pyramid",
    "pyramid14": "pyramid",
    "wedge15": "wedge",
    "wedge18": "wedge",
    "hexahedron20": "hexahedron",
    "hexahedron24": "hexahedron",
    "hexahedron27": "hexahedron",
}


def linear_type(cell_type: str) -> str | None:
    """The linear volume cell type a meshio cell type is drawn as (None: not a volume cell)."""
    cell_type = _QUADRATIC.get(cell_type, cell_type)
    return cell_type if cell_type in _CELL_FACES else None


def boundary(blocks: list[tuple[str, np.ndarray]], points: np.ndarray) -> np.ndarray:
    """Boundary triangles of a mesh of volume cells: ``blocks`` of (meshio cell type, cells), numbered on in
    order across blocks; (t, 4): three node indices and the owning cell. A face shared by two cells is
    interior; each boundary face is turned to point away from its cell's centroid (whatever the file's node
    order), and a quadrilateral becomes two triangles."""
    by_arity: dict[int, tuple[list[np.ndarray], list[np.ndarray]]] = {3: ([], []), 4: ([], [])}
    centroids, first = [], 0
    for cell_type, cells in blocks:
        corners, local = _CELL_FACES[linear_type(cell_type)]
        cells = np.asarray(cells, dtype=np.int64)[:, :corners]
        centroids.append(points[cells].mean(axis=1))
        for face in local:
            nodes, owners = by_arity[len(face)]
            nodes.append(cells[:, face])
            owners.append(np.arange(len(cells)) + first)
        first += len(cells)
    centroid = np.concatenate(centroids) if centroids else np.zeros((0, 3))
    triangles = []
    for arity, (nodes, owners) in by_arity.items():
        if not nodes:
            continue
        faces, owner = np.concatenate(nodes), np.concatenate(owners)
        _, index, counts = np.unique(np.sort(faces, axis=1), axis=0, return_index=True, return_counts=True)
        once = index[counts == 1]
        faces, owner = faces[once], owner[once]
        corner = points[faces]
        normal = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
        inward = np.einsum("ij,ij->i", normal, corner.mean(axis=1) - centroid[owner]) < 0
        faces[inward] = faces[inward, ::-1]
        triangles.append(np.column_stack([faces[:, [0, 1, 2]], owner]))
        if arity == 4:
            triangles.append(np.column_stack([faces[:, [0, 2, 3]], owner]))
    return np.concatenate(triangles) if triangles else np.zeros((0, 4), dtype=np.int64)


def _surface(cells: np.ndarray) -> np.ndarray:
    """Boundary triangles (faces of one tetrahedron only) of a tetrahedral mesh, outward-ordered; (t, 4):
    three node indices and the owning element."""
    cells = np.asarray(cells, dtype=np.int64)[:, :4]
    local = np.array(_CELL_FACES["tetra"][1])
    faces = cells[:, local].reshape(-1, 3)
    owner = np.repeat(np.arange(len(cells)), 4)
    key = np.sort(faces, axis=1)
    _, index, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    once = index[counts == 1]
    return np.column_stack([faces[once], owner[once]])


def face_owner(elements: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The element each boundary triangle belongs to (-1 where none is found)."""
    surface = _surface(elements)
    table = {tuple(sorted(f[:3])): int(f[3]) for f in surface}
    return np.array([table.get(tuple(sorted(t)), -1) for t in np.asarray(triangles, dtype=np.int64)])


def _pick(frames: int) -> np.ndarray:
    if frames <= MAX_FRAMES:
        return np.arange(frames)
    return np.unique(np.round(np.linspace(0, frames - 1, MAX_FRAMES)).astype(np.int64))


def _mesh_out(label, times, positions, triangles, stress, time_label, largest=None) -> dict[str, Any]:
    positions = np.asarray(positions, dtype=float)
    stress = None if stress is None else np.asarray(stress, dtype=float)
    out: dict[str, Any] = {
        "label": label,
        "time_label": time_label,
        "times": [float(t) for t in times],
        "triangles": pack(triangles, "u4"),
        "positions": pack(positions),  # (frames, nodes, 3)
        "frames": int(positions.shape[0]),
        "nodes": int(positions.shape[1]),
        "triangle_count": len(triangles),
    }
    if stress is not None:
        finite = stress[np.isfinite(stress)]
        out["stress"] = pack(stress)  # (frames, triangles) Pa
        # stresses span decades (the grasp against the far edge): from the 1st percentile of the positive
        # ones (at least 1e-4 of the largest) the page colours on a log scale
        positive = finite[finite > 0]
        hi = float(finite.max()) if finite.size else 1.0
        lo = max(float(np.percentile(positive, 1)), hi * 1e-4) if positive.size else 0.0
        out["stress_range"] = [lo, hi] if hi > lo else [0.0, max(hi, 1.0)]
        # the largest stress of each state over every element (the surface shows only the outer ones)
        out["max_stress"] = (
            [float(v) for v in largest]
            if largest is not None
            else [float(np.nanmax(s)) if s.size else 0.0 for s in stress]
        )
    return out


def pvd_entries(text: str) -> list[tuple[float, str]]:
    """(time, file) of each ``<DataSet timestep=... file=...>`` of a ParaView collection."""
    entries = []
    for tag in re.findall(r"<DataSet\b[^>]*>", text):
        t = re.search(r'timestep="([^"]*)"', tag)
        f = re.search(r'file="([^"]*)"', tag)
        if f:
            try:
                time = float(t.group(1)) if t else float(len(entries))
            except ValueError:
                time = float(len(entries))
            entries.append((time, f.group(1)))
    return entries


def _read_vtu(path: Path):
    """Points, the volume cell blocks [(type, cells)], and the stress of each of those cells in order (or None)."""
    import meshio

    mesh = meshio.read(path)
    blocks, stresses = [], []
    name = next((n for n in ("max_principal_stress", "stress", "von_mises") if n in mesh.cell_data), None)
    for block_index, block in enumerate(mesh.cells):
        if linear_type(block.type) is None:  # vertices, lines, surface cells: not tissue
            continue
        cells = np.asarray(block.data, dtype=np.int64)
        blocks.append((block.type, cells))
        if name is not None:
            stresses.append(np.asarray(mesh.cell_data[name][block_index], dtype=float).reshape(len(cells), -1)[:, 0])
    stress = np.concatenate(stresses) if name is not None and stresses else None
    return np.asarray(mesh.points, dtype=float), blocks or None, stress


def simulate_mesh(out: Path, entry: Mapping[str, Any], notes: Notes) -> dict[str, Any] | None:
    """The tissue of a simulate stage: the ``.pvd`` sequence it lists, else its ``.vtu``."""
    files = [f for f in entry.get("files", []) if isinstance(f, str)]
    sequence: list[tuple[float, Path]] = []
    pvd = next((f for f in files if f.endswith(".pvd")), None)
    if pvd is not None:
        path = inside(out, pvd, notes)
        if path is not None:
            base = path.parent
            for t, relative in pvd_entries(path.read_text(errors="replace")):
                try:  # a collection names its files relative to itself
                    within = str((base / relative).resolve().relative_to(out.resolve()))
                except ValueError:
                    notes.add(f"{pvd}: {relative!r} is outside the output directory; not shown")
                    continue
                found = inside(out, within, notes)
                if found is not None:
                    sequence.append((t, found))
    if not sequence:
        vtu = next((f for f in files if f.endswith(".vtu")), None)
        path = inside(out, vtu, notes) if vtu else None
        if path is not None:
            sequence = [(1.0, path)]
    if not sequence:
        return None
    picked = [sequence[i] for i in _pick(len(sequence))]
    positions, stresses, times, largest = [], [], [], []
    surface = None
    for t, path in picked:
        try:
            points, cells, stress = _read_vtu(path)
        except Exception as exc:
            notes.add(f"{path.name}: not readable ({type(exc).__name__}: {exc}); skipped")
            continue
        if cells is None:
            notes.add(f"{path.name}: no volume cells; skipped")
            continue
        if surface is None:
            only_tetra = all(t in ("tetra", "tetra10") for t, _ in cells)
            surface = _surface(cells[0][1]) if only_tetra and len(cells) == 1 else boundary(cells, points)
            count = len(points)
        if len(points) != count:
            notes.add(f"{path.name}: another mesh than the sequence's first; skipped")
            continue
        positions.append(points)
        stresses.append(None if stress is None else stress[surface[:, 3]])
        largest.append(None if stress is None else float(np.max(stress)))
        times.append(t)
    if not positions:
        return None
    stress = None if any(s is None for s in stresses) else np.stack(stresses)
    label = "fraction of the motion applied" if len(times) > 1 else "equilibrium"
    return _mesh_out(
        pvd or "tissue", times, np.stack(positions), surface[:, :3], stress, label, None if stress is None else largest
    )


def states_mesh(out: Path, relative: str, notes: Notes) -> dict[str, Any] | None:
    """The tissue along a retraction trajectory, from ``<stage>-states.npz``."""
    path = inside(out, relative, notes)
    if path is None:
        return None
    try:
        arrays, _ = load_bundle(path)
        positions = np.asarray(arrays["positions"], dtype=float)
        triangles = np.asarray(arrays["triangles"], dtype=np.int64).reshape(-1, 3)
        elements = np.asarray(arrays["elements"], dtype=np.int64)
        stress = np.asarray(arrays["stress"], dtype=float) if "stress" in arrays else None
    except (ValueError, KeyError) as exc:
        notes.add(f"{relative}: not a readable states file ({exc}); not shown")
        return None
    if positions.ndim != 3 or positions.shape[2] != 3 or not len(positions):
        notes.add(f"{relative}: positions are not (states, nodes, 3); not shown")
        return None
    picked = _pick(len(positions))
    per_triangle = None
    if stress is not None and stress.ndim == 2 and len(stress) == len(positions):
        owner = face_owner(elements, triangles)
        per_triangle = np.where(owner[None, :] >= 0, stress[picked][:, np.clip(owner, 0, None)], np.nan)
    largest = None
    if "max_stress" in arrays and len(arrays["max_stress"]) == len(positions):
        largest = np.asarray(arrays["max_stress"], dtype=float)[picked]
    elif stress is not None and stress.ndim == 2 and len(stress) == len(positions):
        largest = stress[picked].max(axis=1)
    mesh = _mesh_out(
        relative, picked.astype(float), positions[picked], triangles, per_triangle, "trajectory state", largest
    )
    if "area_points" in arrays:
        area = np.asarray(arrays["area_points"], dtype=float).reshape(-1, 3)
        visible = np.asarray(arrays.get("visible", np.zeros(len(area))), dtype=bool).ravel()
        if len(visible) == len(area):
            mesh["area"] = {"points": pack(area), "visible": pack(visible.astype(np.uint32), "u4")}
    return mesh
