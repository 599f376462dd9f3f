"""stvk's sparse direct solvers and its stopping floor.

* PARDISO (oneMKL) and SuperLU find the same equilibria; PARDISO's inertia,
  read from its factorisation, matches the signs of the eigenvalues numpy
  computes of the same matrix (dense, an independent measure), for a
  definite tangent (Cholesky) and an indefinite one (Cholesky refuses it,
  LDLT factors it).
* The symbolic analysis is done once per mesh: many solves, one analysis;
  factorisations kept side by side are released when dropped.
* ``linear_solver: pardiso`` where PARDISO cannot load is a clear
  configuration error; ``auto`` falls back to SuperLU.
* The rounding floor is relative to the deformation: a requested residual
  tolerance down to 1e-10 is met (contact and gravity, a flap placed far
  from the origin), where the floor on absolute positions stopped at 4e-8.
"""

from __future__ import annotations

import gc

import numpy as np
import pytest
from fem_support import lifted
from surgiplan.plugins.fem import StVKModel, StVKSettings, linear

needs_pardiso = pytest.mark.skipif(
    not linear.pardiso_available()[0], reason="PARDISO (pypardiso, oneMKL) not installed"
)

FLAP = (0.03, 0.03, 0.002)


def flap(linear_solver="auto", origin=(0.0, 0.0, 0.0), tolerance=1e-6):
    lo = np.asarray(origin, dtype=float)
    return StVKModel(
        StVKSettings.model_validate(
            {
                "mesh": {"box": {"size": list(FLAP), "divisions": [6, 6, 2], "pattern": "five", "origin": lo.tolist()}},
                "anchored": [{"region": {"min": lo.tolist(), "max": np.add(lo, [0.0, FLAP[1], FLAP[2]]).tolist()}}],
                "grasp": {
                    "region": {
                        "min": np.add(lo, [0.0275, 0.0125, 0]).tolist(),
                        "max": np.add(lo, [0.03, 0.0175, 0.002]).tolist(),
                    }
                },
                "base_plane": {"point": lo.tolist()},
                "solver": {"linear_solver": linear_solver, "residual_tol": tolerance},
            }
        )
    )


@needs_pardiso
def test_pardiso_and_superlu_find_the_same_equilibrium():
    states = {}
    for solver in ("pardiso", "superlu"):
        m = flap(solver, tolerance=1e-10)
        start = m.solve(lifted(m, 0.004))
        states[solver] = m.solve(lifted(m, 0.009, 0.4), initial=start)
        assert states[solver].converged and states[solver].data["linear_solver"] == solver
    a, b = states["pardiso"], states["superlu"]
    moved = np.abs(a.positions - flap().rest_nodes).max()
    assert np.abs(a.positions - b.positions).max() < 1e-9 * moved
    assert a.energy == pytest.approx(b.energy, rel=1e-10)
    assert np.abs(a.reaction_forces - b.reaction_forces).max() < 1e-8 * np.abs(b.reaction_forces).max()


def _tangent(m, constraints, state, shift=0.0):
    solver = m.solver
    prescribed, _ = m._prescribed(constraints)
    _, _, data = solver.tangent(state.positions.ravel(), False)
    constrained = solver.pattern.constrain(data, prescribed)
    constrained[solver.pattern.diagonal[~prescribed]] += shift
    return solver.pattern, constrained


@needs_pardiso
def test_the_inertia_read_from_the_factorisation_matches_the_eigenvalues():
    m = flap("pardiso")
    constraints = lifted(m, 0.006, 0.3)
    state = m.solve(constraints)
    for shift in (0.0, -2e3):  # the tangent at an equilibrium, then shifted down until it is indefinite
        pattern, values = _tangent(m, constraints, state, shift)
        eigenvalues = np.linalg.eigvalsh(pattern.matrix(values).toarray())
        factor = pattern.factorize(values)
        assert factor.inertia == (int((eigenvalues > 0).sum()), int((eigenvalues < 0).sum()), 0)
        # definite: factored by Cholesky alone; indefinite: Cholesky refuses, and LDLT gives the inertia above
        assert factor._handle.mtype == (linear.CHOLESKY if eigenvalues.min() > 0 else linear.MTYPE)
        if eigenvalues.min() < 0:
            with pytest.raises(linear.NotPositiveDefinite):
                pattern.factorize(values, definite_only=True)
        assert factor.positive_pivots() == bool(eigenvalues.min() > 0)
        rhs = np.random.default_rng(1).normal(size=len(eigenvalues))
        dense = pattern.matrix(values).toarray()[np.ix_(pattern.new_of_old, pattern.new_of_old)]
        assert np.allclose(dense @ factor.solve(rhs), rhs, rtol=1e-9, atol=1e-9 * np.abs(rhs).max())
    assert shift < 0 and eigenvalues.min() < 0  # the second matrix was indefinite


@needs_pardiso
def test_one_symbolic_analysis_serves_every_solve_and_factors_are_released():
    m = flap("pardiso")
    state = None
    total = 0
    for dz in np.linspace(0.001, 0.012, 8):
        state = m.solve(lifted(m, dz, 20 * dz), initial=state)
        assert state.converged
        total += state.data["factorizations"]
    solver = m.solver.pattern._pardiso
    # one analysis per matrix type (Cholesky for definite tangents, LDLT where one was indefinite), one ordering
    assert total > 8 and len(solver.cholesky) == 1 and solver.cholesky[0].analysed and len(solver.handles) <= 1
    assert all(handle.ordering == solver.ordering for handle in solver.cholesky + solver.handles)
    m.clear_caches()
    del state
    gc.collect()
    for handle in solver.cholesky + solver.handles:
        # every factorisation released: its slot free, the memory of at most KEPT of them kept for reuse
        assert len(handle.free) + len(handle.kept) == linear.SLOTS and len(handle.kept) <= linear.KEPT
        assert sorted(handle.free + handle.kept) == list(range(1, linear.SLOTS + 1))


@needs_pardiso
def test_a_singular_matrix_is_not_taken_for_a_definite_one():
    m = flap("pardiso")
    pattern, values = _tangent(m, m.stage_constraints(), m.solve(m.stage_constraints()))
    values[pattern.diagonal[:6]] = 0.0  # a zero pivot: PARDISO perturbs it, and says so
    values[np.isin(pattern.indices, np.arange(6)) | np.isin(pattern.entry_cols, np.arange(6))] = 0.0
    try:
        factor = pattern.factorize(values)
    except linear.SingularMatrix:
        return
    assert factor.perturbed > 0 or factor.inertia[2] > 0
    assert not factor.positive_pivots()


def test_pardiso_where_it_cannot_load_is_a_configuration_error(monkeypatch):
    from pydantic import ValidationError

    monkeypatch.setattr(linear, "pardiso_available", lambda: (False, "ImportError: no oneMKL"))
    monkeypatch.setattr(linear, "_PARDISO_FUNCTION", None)
    monkeypatch.setattr(linear, "_PARDISO_ERROR", "ImportError: no oneMKL")
    mesh = {"box": {"size": [0.01, 0.01, 0.01], "divisions": [1, 1, 1]}}
    with pytest.raises(ValidationError, match=r"linear_solver 'pardiso' needs pypardiso .*surgiplan\[pardiso\]"):
        StVKSettings.model_validate({"mesh": mesh, "solver": {"linear_solver": "pardiso"}})
    assert linear.resolve("auto") == "superlu"  # auto falls back


@pytest.mark.parametrize("tolerance", [1e-8, 1e-10])
def test_a_tolerance_down_to_1e_10_is_honoured_with_contact_and_gravity(tolerance):
    # placed 0.3 m from the origin: the floor on absolute positions (eps |K| |x|) stopped such a flap at 4e-8
    m = flap(origin=(0.3, -0.2, 0.05), tolerance=tolerance)
    for constraints in (lifted(m, 0.005, 0.3), m.grasp_constraints(m.grasped_nodes(), None)):
        state = m.solve(constraints)
        assert state.converged
        assert state.residual <= tolerance * state.data["residual_scale"]
    assert state.data["contact_energy"] > 0  # the flap held at rest lies on the base plane
    # the weight is carried by the anchors, the gripper and the base plane: within the tolerance
    weight = 9.8 * m.node_masses.sum()
    plane = m.loads.base
    depth = plane.depth(state.positions)
    contact = -plane.stiffness * depth[depth < 0].sum()
    carried = state.reaction_forces[:, 2].sum() + contact
    assert carried == pytest.approx(weight, rel=100 * tolerance)
