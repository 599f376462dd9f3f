"""Helpers for the stvk tests: small models and independent references (elastica, analytic StVK)."""

from __future__ import annotations

import numpy as np
from scipy.integrate import quad, solve_bvp
from scipy.optimize import brentq
from surgiplan.plugins.fem import StVKModel, StVKSettings


def model(size, divisions, *, pattern="six", material=None, **settings) -> StVKModel:
    """A box-mesh model; ``settings`` are further StVKSettings fields (SI)."""
    data = {
        "mesh": {"box": {"size": list(size), "divisions": list(divisions), "pattern": pattern}},
        "material": material or {},
        **settings,
    }
    return StVKModel(StVKSettings.model_validate(data))


def face(axis: int, value: float, size) -> dict:
    """The region of a box's face ``axis = value``."""
    lo = [0.0, 0.0, 0.0]
    hi = list(size)
    lo[axis] = hi[axis] = value
    return {"min": lo, "max": hi}


def elastica_tip(alpha: float) -> tuple[float, float]:
    """Tip deflection and horizontal reach over L of a cantilever under a dead tip load, alpha = P L^2 / EI.

    Bisshopp & Drucker (1945): the inextensible elastica ``theta'' = -alpha cos(theta)``,
    ``theta(0) = 0``, ``theta'(1) = 0`` (arc length over L), solved as a boundary value problem.
    """
    s = np.linspace(0.0, 1.0, 201)
    guess = np.vstack([0.5 * alpha * (s - s**2 / 2), 0.5 * alpha * (1 - s)])
    sol = solve_bvp(
        lambda _, y: np.vstack([y[1], -alpha * np.cos(y[0])]),
        lambda a, b: np.array([a[0], b[1]]),
        s,
        guess,
        tol=1e-10,
        max_nodes=100_000,
    )
    assert sol.success
    deflection = quad(lambda t: np.sin(sol.sol(t)[0]), 0, 1, epsabs=1e-13)[0]
    reach = quad(lambda t: np.cos(sol.sol(t)[0]), 0, 1, epsabs=1e-13)[0]
    return deflection, reach


def uniaxial_stvk(stretch: float, youngs: float, poisson: float, kappa: float) -> tuple[float, float]:
    """Lateral stretch b and nominal stress P_11 (Pa) of StVK + kappa/2 (ln J)^2 in uniaxial tension.

    F = diag(a, b, b) with a traction-free sides: S_22 = 0 solved for b.
    """
    lam = youngs * poisson / ((1 + poisson) * (1 - 2 * poisson))
    mu = youngs / (2 * (1 + poisson))
    a = stretch

    def stresses(b):
        e11, e22 = (a * a - 1) / 2, (b * b - 1) / 2
        tr = e11 + 2 * e22
        log_j = np.log(a * b * b)
        s11 = lam * tr + 2 * mu * e11 + kappa * log_j / a**2
        s22 = lam * tr + 2 * mu * e22 + kappa * log_j / b**2
        return s11, s22

    b = brentq(lambda b: stresses(b)[1], 0.3, 1.5, xtol=1e-15)
    return b, a * stresses(b)[0]


def on(m: StVKModel, region: dict) -> np.ndarray:
    """The nodes of ``m`` in a region given as ``{"min": ..., "max": ...}``."""
    return m.nodes_in_region(region["min"], region["max"])


def lifted(m: StVKModel, dz: float, tilt: float = 0.0):
    """The grasp constraints that lift a model's jaws by ``dz`` (m) and tilt them by ``tilt`` (rad) about y,
    about the jaws' centre."""
    pose = np.eye(4)
    c, s = np.cos(tilt), np.sin(tilt)
    pose[:3, :3] = [[c, 0, -s], [0, 1, 0], [s, 0, c]]
    centre = m.rest_nodes[m.grasped_nodes()].mean(axis=0)
    pose[:3, 3] = centre + np.array([0.0, 0.0, dz]) - pose[:3, :3] @ centre
    return m.grasp_constraints(m.grasped_nodes(), pose)
