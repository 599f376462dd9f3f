"""Writing equilibrium states as VTK unstructured grids (``.vtu``) for ParaView or any VTK viewer.

The file holds the deformed mesh (points at the deformed positions, linear
``tetra`` or quadratic ``tetra10`` cells) with, per node, ``displacement`` (m) and ``reaction_force``
(N, non-zero on held nodes) and, per element, ``max_principal_stress``
(Pa, the largest absolute principal second Piola-Kirchhoff stress),
``volume_ratio`` (J = deformed / rest volume) and ``youngs_modulus`` (Pa).
Warp by ``displacement`` with a factor of -1 to see the rest shape.
Written atomically: a temporary file in the same directory, then renamed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from surgiplan.storage import commit_file, temporary_path


def write_vtu(
    path: str | Path,
    rest: np.ndarray,
    tets: np.ndarray,
    positions: np.ndarray,
    point_data: dict[str, np.ndarray] | None = None,
    cell_data: dict[str, np.ndarray] | None = None,
) -> Path:
    """Write the deformed mesh to ``path`` (.vtu) atomically; returns the path."""
    import meshio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    points = {"displacement": np.asarray(positions) - np.asarray(rest)}
    points.update({k: np.asarray(v, dtype=float) for k, v in (point_data or {}).items()})
    cells = {k: [np.asarray(v, dtype=float)] for k, v in (cell_data or {}).items()}
    tets = np.asarray(tets)
    cell_type = "tetra10" if tets.shape[1] == 10 else "tetra"
    mesh = meshio.Mesh(np.asarray(positions, dtype=float), [(cell_type, tets)], point_data=points, cell_data=cells)
    tmp = temporary_path(path, ".vtu")
    try:
        meshio.write(tmp, mesh, file_format="vtu")
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    commit_file(tmp, path)  # synced, renamed into place, the directory synced
    return path
