"""Per-element material of the ``stvk`` model: Lamé parameters, volume penalty, density.

Patil & Alterovitz (§V, §VI scenario 2) model tissue as isotropic St.
Venant-Kirchhoff, possibly heterogeneous (stiffer veins segmented from a
thresholded image of the tissue and mapped onto the flap's elements). Here
every element has its own Young's modulus E (Pa), Poisson's ratio nu and
density rho (kg/m^3), converted to Lamé parameters

    lambda = E nu / ((1 + nu)(1 - 2 nu)),   mu = E / (2 (1 + nu)),

and a volume-penalty modulus ``kappa = volume_penalty * K`` (Pa), a fraction
of the bulk modulus ``K = lambda + 2 mu / 3`` (Teschner et al. 2004, the
paper's ref. [23]: forces against the change of volume, for nearly
incompressible tissue and against inverted elements). The penalty adds
``kappa`` to the small-strain bulk modulus: with the default 0.1 and
nu = 0.45, the small-strain Poisson's ratio becomes 0.454 and E rises by 0.3 %.

:class:`MaterialField` is built from the base values and a list of
overrides, each selecting elements by their rest centroid: an axis-aligned
``region`` box or a thresholded grey-scale ``image`` laid over the x-y
extent of the mesh (dark or bright pixels, see :class:`ImageMap`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from surgiplan.errors import ConfigError


def lame_parameters(youngs_modulus, poisson_ratio) -> tuple[np.ndarray, np.ndarray]:
    """(lambda, mu) in Pa from Young's modulus (Pa) and Poisson's ratio, elementwise."""
    e = np.asarray(youngs_modulus, dtype=float)
    nu = np.asarray(poisson_ratio, dtype=float)
    return e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu)), e / (2.0 * (1.0 + nu))


@dataclass
class MaterialField:
    """Per-element E (Pa), nu, rho (kg/m^3) and the volume-penalty fraction of the bulk modulus."""

    youngs_modulus: np.ndarray
    poisson_ratio: np.ndarray
    density: np.ndarray
    volume_penalty: float = 0.1

    def __post_init__(self) -> None:
        self.youngs_modulus = np.asarray(self.youngs_modulus, dtype=float)
        self.poisson_ratio = np.asarray(self.poisson_ratio, dtype=float)
        self.density = np.asarray(self.density, dtype=float)
        if np.any(self.youngs_modulus <= 0) or np.any(self.density < 0):
            raise ConfigError("Young's modulus must be positive and density non-negative")
        if np.any(self.poisson_ratio < -1) or np.any(self.poisson_ratio >= 0.5):
            raise ConfigError("Poisson's ratio must lie in [-1, 0.5)")
        if self.volume_penalty < 0:
            raise ConfigError("volume_penalty must be non-negative")

    @classmethod
    def uniform(cls, n_elements: int, youngs_modulus: float, poisson_ratio: float, density: float, **kw):
        full = np.full
        return cls(full(n_elements, youngs_modulus), full(n_elements, poisson_ratio), full(n_elements, density), **kw)

    @property
    def lame(self) -> tuple[np.ndarray, np.ndarray]:
        return lame_parameters(self.youngs_modulus, self.poisson_ratio)

    @property
    def bulk_modulus(self) -> np.ndarray:
        lam, mu = self.lame
        return lam + 2.0 * mu / 3.0

    @property
    def penalty_modulus(self) -> np.ndarray:
        """kappa (Pa) per element."""
        return self.volume_penalty * self.bulk_modulus

    def override(self, mask, youngs_modulus=None, poisson_ratio=None, density=None) -> None:
        """Set the given properties on the elements in ``mask`` (bool (m,))."""
        mask = np.asarray(mask, dtype=bool)
        for name, value in (
            ("youngs_modulus", youngs_modulus),
            ("poisson_ratio", poisson_ratio),
            ("density", density),
        ):
            if value is not None:
                getattr(self, name)[mask] = value
        self.__post_init__()


@dataclass
class ImageMap:
    """A grey-scale image laid over the rectangle ``lower``-``upper`` (m) of the x-y plane.

    An element is selected when the image's intensity (0 black to 1 white)
    at its rest centroid is below ``threshold`` (``dark=True``: dark veins on
    a light background, the default) or above it (``dark=False``). Centroids
    outside the rectangle are not selected. Row 0 of the image is at
    ``upper`` y (images are stored top row first).
    """

    intensity: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    threshold: float = 0.5
    dark: bool = True

    @classmethod
    def read(cls, path: str | Path, lower, upper, threshold: float = 0.5, dark: bool = True, location=None):
        import matplotlib.image

        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"image file not found: {path}", location=location)
        try:
            image = np.asarray(matplotlib.image.imread(path), dtype=float)
        except Exception as exc:  # Pillow and matplotlib raise many types
            raise ConfigError(f"cannot read image {path}: {exc}", location=location) from None
        if image.ndim == 3:
            image = image[..., :3].mean(axis=2)
        if image.max() > 1.0:
            image = image / 255.0
        return cls(image, np.asarray(lower, float)[:2], np.asarray(upper, float)[:2], threshold, dark)

    def select(self, points) -> np.ndarray:
        """Boolean mask of the points (k, 3) whose pixel passes the threshold."""
        points = np.asarray(points, dtype=float)
        rows, cols = self.intensity.shape
        u = (points[:, 0] - self.lower[0]) / (self.upper[0] - self.lower[0])
        v = (points[:, 1] - self.lower[1]) / (self.upper[1] - self.lower[1])
        inside = (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
        col = np.clip((u * cols).astype(int), 0, cols - 1)
        row = np.clip(((1.0 - v) * rows).astype(int), 0, rows - 1)
        value = self.intensity[row, col]
        passed = value < self.threshold if self.dark else value > self.threshold
        return inside & passed
