"""Occupancy grids (a voxelised scan) as obstacles: occupied voxels merged into few boxes by greedy meshing.

A grid is a 3D array (index ``[i, j, k]`` along x, y, z) whose voxel ``[i, j, k]`` spans
``origin + voxel * [i, j, k]`` to ``origin + voxel * [i + 1, j + 1, k + 1]``; it comes from a NumPy ``.npy`` or
``.npz`` file (occupied: a value at least ``threshold``; booleans: True) or from a point cloud (a PLY, or any
file trimesh reads as points: the voxel holding a point is occupied).

The rule that turns voxels into boxes (:func:`greedy_boxes`), so that a scan of a trainer does not become one
obstacle a voxel: visit the voxels in array order (``i``, then ``j``, then ``k``); from each occupied voxel not
yet in a box, grow a run along z while the next voxel is occupied and free, then grow that run along y while
the whole next row is, then the rectangle along x while the whole next slab is; the block found is one box and
its voxels are taken. The boxes cover exactly the occupied voxels, none twice, so every distance to the scene is
the distance to the voxels themselves; a solid block of voxels becomes one box, and a scanned surface a few
boxes per row instead of one per voxel.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numba import njit

from ..errors import SceneError
from .compiled import _FLAGS

#: the most voxels a grid may have (a 512^3 grid); larger files are refused before they are read whole
MAX_VOXELS = 512**3


@njit(**_FLAGS)
def _greedy(occupied, out):
    """Fill ``out`` (n, 6): each box's voxel index range ``i0, j0, k0, i1, j1, k1`` (end exclusive); the count."""
    ni, nj, nk = occupied.shape
    taken = np.zeros(occupied.shape, dtype=np.bool_)
    n = 0
    for i in range(ni):
        for j in range(nj):
            for k in range(nk):
                if not occupied[i, j, k] or taken[i, j, k]:
                    continue
                k1 = k + 1
                while k1 < nk and occupied[i, j, k1] and not taken[i, j, k1]:
                    k1 += 1
                j1 = j + 1
                while j1 < nj:
                    whole = True
                    for kk in range(k, k1):
                        if not occupied[i, j1, kk] or taken[i, j1, kk]:
                            whole = False
                            break
                    if not whole:
                        break
                    j1 += 1
                i1 = i + 1
                while i1 < ni:
                    whole = True
                    for jj in range(j, j1):
                        for kk in range(k, k1):
                            if not occupied[i1, jj, kk] or taken[i1, jj, kk]:
                                whole = False
                                break
                        if not whole:
                            break
                    if not whole:
                        break
                    i1 += 1
                taken[i:i1, j:j1, k:k1] = True
                out[n, 0], out[n, 1], out[n, 2] = i, j, k
                out[n, 3], out[n, 4], out[n, 5] = i1, j1, k1
                n += 1
    return n


def greedy_boxes(occupied: np.ndarray) -> np.ndarray:
    """The occupied voxels of a boolean (ni, nj, nk) array as boxes of voxels, (n, 6) ``i0 j0 k0 i1 j1 k1``
    (end exclusive), by the rule of this module's description."""
    occupied = np.ascontiguousarray(occupied, dtype=np.bool_)
    out = np.empty((int(occupied.sum()), 6), dtype=np.int64)
    n = _greedy(occupied, out)
    return out[:n]


def boxes_in_space(boxes: np.ndarray, voxel: np.ndarray, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centres and sizes (same unit as ``voxel`` and ``origin``) of voxel index boxes."""
    lo = origin + boxes[:, :3] * voxel
    hi = origin + boxes[:, 3:] * voxel
    return 0.5 * (lo + hi), hi - lo


def read_grid(path: Path, key: str | None, threshold: float, location: str) -> np.ndarray:
    """The occupied voxels of a ``.npy``/``.npz`` grid file, as a boolean 3D array; :class:`SceneError` naming
    the file and what is wrong (missing, unreadable, not 3D, not numeric, too large, an unknown ``key``)."""
    if not path.is_file():
        raise SceneError(f"occupancy grid file not found: {path}", location=f"{location}.file")
    try:
        loaded = np.load(path, allow_pickle=False, mmap_mode="r")  # a .npy: its shape read before its voxels
        if isinstance(loaded, np.lib.npyio.NpzFile):
            with loaded:
                array = _member(loaded, path, key, location)
        elif key is not None:
            raise SceneError(f"{path} is a .npy file (one array): 'key' is for .npz files", location=f"{location}.key")
        else:
            array = loaded
        return _occupied(array, path, threshold, location)
    except SceneError:
        raise
    except Exception as exc:  # numpy raises ValueError, OSError, zipfile errors, ... for damaged files
        raise SceneError(f"cannot read occupancy grid {path}: {exc}", location=f"{location}.file") from None


def _member(loaded, path: Path, key: str | None, location: str) -> np.ndarray:
    names = list(loaded.files)
    if key is None and len(names) != 1:
        raise SceneError(
            f"{path} holds {len(names)} arrays ({', '.join(names) or 'none'}): name one with 'key'",
            location=f"{location}.key",
        )
    name = key if key is not None else names[0]
    if name not in names:
        raise SceneError(f"{path} has no array '{name}' (it holds: {', '.join(names)})", location=f"{location}.key")
    return loaded[name]


def _occupied(array, path: Path, threshold: float, location: str) -> np.ndarray:
    if array.ndim != 3:
        raise SceneError(
            f"{path}: an occupancy grid is a 3D array (x, y, z); this one has shape {tuple(array.shape)}",
            location=f"{location}.file",
        )
    if array.size > MAX_VOXELS:
        raise SceneError(
            f"{path}: {array.size:,} voxels, more than the {MAX_VOXELS:,} a grid may have", location=f"{location}.file"
        )
    if array.dtype == np.bool_:
        return np.asarray(array)
    if array.dtype.kind not in "iuf":
        raise SceneError(f"{path}: voxels must be booleans or numbers, not {array.dtype}", location=f"{location}.file")
    values = np.asarray(array)
    if array.dtype.kind == "f" and not np.all(np.isfinite(values)):
        raise SceneError(f"{path}: the grid holds NaN or infinite values", location=f"{location}.file")
    return values >= threshold


def read_points(path: Path, scale: float, location: str) -> np.ndarray:
    """The points (m) of a point cloud file (PLY, or anything trimesh reads as points or a mesh's vertices)."""
    import trimesh

    if not path.is_file():
        raise SceneError(f"point cloud file not found: {path}", location=f"{location}.points")
    try:
        loaded = trimesh.load(path, process=False)
    except Exception as exc:  # trimesh raises many types for bad files
        raise SceneError(f"cannot read point cloud {path}: {exc}", location=f"{location}.points") from None
    points = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=float).reshape(-1, 3)
    if len(points) == 0:
        raise SceneError(f"point cloud {path} holds no points", location=f"{location}.points")
    if not np.all(np.isfinite(points)):
        raise SceneError(f"point cloud {path} has non-finite coordinates", location=f"{location}.points")
    return points * scale


def voxelise(points: np.ndarray, voxel: np.ndarray, origin: np.ndarray, location: str) -> np.ndarray:
    """The boolean grid whose voxel holding each point is occupied (the grid starts at ``origin``)."""
    index = np.floor((points - origin) / voxel).astype(np.int64)
    if np.any(index < 0):
        raise SceneError(
            f"{int(np.any(index < 0, axis=1).sum())} points lie below the grid's origin", location=f"{location}.origin"
        )
    shape = index.max(axis=0) + 1
    if int(np.prod(shape)) > MAX_VOXELS:
        raise SceneError(
            f"the points span {' x '.join(str(s) for s in shape)} voxels, more than {MAX_VOXELS:,}: a larger "
            "voxel_size?",
            location=f"{location}.voxel_size",
        )
    grid = np.zeros(tuple(shape), dtype=np.bool_)
    grid[index[:, 0], index[:, 1], index[:, 2]] = True
    return grid


greedy_boxes(np.ones((2, 2, 2), dtype=np.bool_))  # compiled (or loaded from numba's cache) on import
