"""Writes scanned_trainer.npz: the occupancy grid of a box trainer as a scan at 2 mm would give it.

A 200 x 150 x 60 mm trainer (100 x 75 x 30 voxels): its floor, two side walls, a partition whose window is the
only way through, an "organ" (an ellipsoid resting on the floor), two pegs and a bridge that leaves a gap to pass
under. Reproducible (no randomness); the file is a compressed boolean array ``occupancy`` indexed [x, y, z].

    python configs/scenes/scanned_trainer.py
"""

from pathlib import Path

import numpy as np

VOXEL_MM = 2.0
SHAPE = (100, 75, 30)


def trainer() -> np.ndarray:
    x, y, z = (np.arange(n) * VOXEL_MM + VOXEL_MM / 2 for n in SHAPE)
    x, y, z = np.meshgrid(x, y, z, indexing="ij")
    grid = z < 4.0  # the floor, 4 mm thick
    grid |= (y < 4.0) | (y > 146.0)  # the side walls
    grid |= ((x - 100) / 30) ** 2 + ((y - 40) / 25) ** 2 + ((z - 4) / 18) ** 2 <= 1.0  # the organ
    for px, py in ((60.0, 105.0), (140.0, 110.0)):  # two pegs, 8 mm across, 40 mm tall
        grid |= (np.hypot(x - px, y - py) <= 4.0) & (z < 40.0)
    grid |= (np.abs(x - 100) < 5.0) & (y > 60.0) & (y < 146.0) & (z > 30.0) & (z < 36.0)  # a bridge, 30 mm up
    window = (y > 60.0) & (y < 90.0) & (z > 16.0) & (z < 40.0)
    grid |= (np.abs(x - 50) < 3.0) & ~window  # a partition, 6 mm thick, with a window 30 x 24 mm
    return grid


if __name__ == "__main__":
    path = Path(__file__).with_name("scanned_trainer.npz")
    np.savez_compressed(path, occupancy=trainer())
    print(path, path.stat().st_size, "bytes")
