"""Draw configs/retraction/veins.png: the tissue texture of paper 002's scenario 2, veins dark on light.

The paper segments the vessels of a tissue texture by thresholding its image
and gives the vein elements E = 1 MPa, the rest 250 kPa. This image plays the
texture: three sinuous veins run along the flap's whole length (y), with a
branch, over a mottled background that stays above the threshold.
Run from the repository: .venv/bin/python configs/retraction/make_veins.py
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

size = 256  # pixels over the 50 mm flap
rng = np.random.default_rng(2)
y = np.linspace(0, 1, 400)
fig = plt.figure(figsize=(size / 100, size / 100), dpi=100)
ax = fig.add_axes((0, 0, 1, 1))
noise = 0.8 + 0.15 * rng.random((64, 64))
ax.imshow(noise, cmap="gray", vmin=0, vmax=1, extent=(0, 1, 0, 1), interpolation="bicubic")
for x0, amplitude, phase, width in [(0.22, 0.05, 0.0, 5.0), (0.52, 0.07, 1.3, 6.5), (0.8, 0.04, 2.1, 4.5)]:
    ax.plot(x0 + amplitude * np.sin(2 * np.pi * 1.3 * y + phase), y, color="#3a0d0d", linewidth=width)
branch = y[y > 0.45]
ax.plot(
    0.52 + 0.07 * np.sin(2 * np.pi * 1.3 * 0.45 + 1.3) + 0.5 * (branch - 0.45) ** 1.2,
    branch,
    color="#3a0d0d",
    linewidth=3.5,
)
ax.set_xlim(0, 1)
ax.set_ylim(0, 1)
ax.axis("off")
fig.savefig(Path(__file__).with_name("veins.png"), dpi=100)
