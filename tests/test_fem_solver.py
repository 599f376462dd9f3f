"""stvk's solver contract: degenerate states are answered, answers do not depend on history, reactions.

* A degenerate configuration (an element crushed to a volume ratio of
  1e-100, positions that are not numbers) gives a state with the reason,
  never an exception (it used to raise LinAlgError from the stress).
* A solve is a function of its constraints and its start positions: the
  same warm-started solve gives the same bits whatever the model solved
  before, with or without its kept factorisations, in a fresh model;
  the start state's ``tangent_shift`` (where an indefinite tangent's
  diagonal shift starts) is one of those inputs.
* A large motion is predicted in two Euler steps and reaches the
  equilibrium one step reaches, with fewer iterations.
* ``EquilibriumState.reaction_forces`` (the interface's field) is, row by
  row in the constraints' order, dΠ/d(prescribed position): checked against
  central differences of Π over re-solved equilibria, and against the
  weight the supports carry.
* The quasi-Newton corrector finds the equilibrium plain Newton finds.
"""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest
from fem_support import face, lifted, model, on
from surgiplan.deformable import Constraints
from surgiplan.plugins.fem import AxisConstraints
from surgiplan.plugins.fem.newton import EquilibriumSolver

FLAP = (0.03, 0.03, 0.002)


def flap(**settings):
    return model(
        FLAP,
        (6, 6, 2),
        pattern="five",
        anchored=[{"region": face(0, 0.0, FLAP)}],
        grasp={"region": {"min": [0.0275, 0.0125, 0], "max": [0.03, 0.0175, 0.002]}},
        base_plane={},
        **settings,
    )


def test_an_element_crushed_flat_gives_a_state_not_an_exception():
    m = model((0.01, 0.01, 0.01), (1, 1, 1))
    crushed = m.rest_nodes * [1.0, 1.0, 1e-100]  # every element's volume ratio 1e-100 > 0: not inverted
    assert np.all(m.kernel.volume_ratio(crushed) > 0)
    every = Constraints(np.arange(m.mesh.n_nodes), crushed)
    for state in (m.evaluate_state(crushed), m.solve(every)):  # the solve moves every node there from rest
        assert state.valid  # nothing inverted, the surface does not cross itself
        assert np.all(np.isinf(state.stress))  # the volume penalty's stress is unbounded there
    assert m.solve(every).converged  # nothing is free: the prescribed motion is the equilibrium


def test_the_stress_of_a_nearly_singular_deformation_is_finite_and_exact():
    m = model((0.01, 0.01, 0.01), (1, 1, 1), material={"youngs_modulus": 1e6, "poisson_ratio": 0.3})
    squeezed = m.rest_nodes * [1.0, 1.0, 1e-6]
    s = m.kernel.second_piola_kirchhoff(squeezed)
    f = np.diag([1.0, 1.0, 1e-6])
    lam, mu, kappa = m.kernel.lam[0], m.kernel.mu[0], m.kernel.kappa[0]
    e = 0.5 * (f.T @ f - np.eye(3))
    expected = lam * np.trace(e) * np.eye(3) + 2 * mu * e + kappa * np.log(1e-6) * np.linalg.inv(f.T @ f)
    assert np.allclose(s, expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())


def test_positions_that_are_not_numbers_are_invalid_with_the_reason():
    m = flap()
    broken = m.rest_nodes.copy()
    broken[3] = np.nan
    state = m.evaluate_state(broken)
    assert not state.valid and not state.converged
    assert "not finite" in state.message
    # as a warm start they are ignored: the solve starts from rest and finds the equilibrium
    bad_start = dataclasses.replace(m.solve(lifted(m, 0.002)), positions=broken)
    from_rest = m.solve(lifted(m, 0.004))
    assert m.solve(lifted(m, 0.004), initial=bad_start).positions.tobytes() == from_rest.positions.tobytes()


def _same(a, b) -> bool:
    return (
        a.positions.tobytes() == b.positions.tobytes()
        and a.stress.tobytes() == b.stress.tobytes()
        and a.energy == b.energy
        and a.iterations == b.iterations
        and a.reaction_forces.tobytes() == b.reaction_forces.tobytes()
    )


def test_a_warm_started_solve_does_not_depend_on_what_was_solved_before():
    m = flap()
    start = m.solve(lifted(m, 0.004))
    first = m.solve(lifted(m, 0.007, 0.3), initial=start)
    assert first.converged and first.iterations > 1
    for dz, tilt in [(0.010, -0.4), (0.002, 0.2), (0.012, 0.0)]:  # other solves in between, other states
        m.solve(lifted(m, dz, tilt), initial=m.solve(lifted(m, dz / 2)))
    again = m.solve(lifted(m, 0.007, 0.3), initial=start)
    assert _same(first, again)
    m.clear_caches()  # the kept factorisation at the start positions is gone: computed again, same bits
    assert _same(first, m.solve(lifted(m, 0.007, 0.3), initial=start))
    fresh = pickle.loads(pickle.dumps(flap()))  # as a worker process gets it
    assert _same(first, fresh.solve(lifted(fresh, 0.007, 0.3), initial=start))


def test_a_kept_factorisation_is_used_only_from_the_positions_it_was_computed_at():
    m = flap()
    start = m.solve(lifted(m, 0.004))
    target = lifted(m, 0.007, 0.3)
    m.solve(lifted(m, 0.006), initial=start)  # keeps the tangent factored at start.positions
    hit = m.solve(target, initial=start)
    m.clear_caches()
    miss = m.solve(target, initial=start)
    assert _same(hit, miss) and hit.data["factorizations"] == miss.data["factorizations"] - 1
    nudged = dataclasses.replace(start, positions=start.positions + 1e-12)  # other positions: computed anew
    m.solve(lifted(m, 0.006), initial=start)
    other = m.solve(target, initial=nudged)
    m.clear_caches()
    assert _same(other, m.solve(target, initial=nudged))
    assert np.abs(other.positions - hit.positions).max() < 1e-6 * FLAP[0]  # the same equilibrium


def test_reaction_forces_are_the_derivative_of_the_energy_in_the_constraints_order():
    m = flap(solver={"residual_tol": 1e-10})
    constraints = lifted(m, 0.006, 0.25)
    state = m.solve(constraints)
    assert state.converged
    nodes = constraints.prescribed_nodes
    assert state.reaction_forces.shape == (len(nodes), 3)
    assert np.array_equal(state.reaction_forces, state.data["reaction_field"][nodes])
    jaws = m.grasped_nodes()
    row = int(np.flatnonzero(nodes == jaws[len(jaws) // 2])[0])
    h = 1e-7
    for axis in range(3):
        energies = []
        for sign in (1, -1):
            moved = dataclasses.replace(constraints, prescribed_positions=constraints.prescribed_positions.copy())
            moved.prescribed_positions[row, axis] += sign * h
            energies.append(m.solve(moved, initial=state).energy)
        derivative = (energies[0] - energies[1]) / (2 * h)
        assert derivative == pytest.approx(state.reaction_forces[row, axis], rel=1e-4, abs=1e-6)


def test_the_supports_carry_the_weight_and_a_free_axis_carries_nothing():
    size = (0.02, 0.01, 0.004)
    m = model(size, (4, 2, 2), solver={"residual_tol": 1e-10})
    bottom = on(m, face(2, 0.0, size))
    held = np.zeros((len(bottom), 3), dtype=bool)
    held[:, 2] = True  # rollers: only z is held
    corner = np.flatnonzero(np.all(m.rest_nodes == 0.0, axis=1))  # and one node fully, against rigid motion
    nodes = np.concatenate([bottom, corner, corner])  # a node listed twice gets its reaction in both rows
    axes = np.concatenate([held, np.ones((2, 3), dtype=bool)])
    state = m.solve(AxisConstraints(nodes, m.rest_nodes[nodes], None, axes))
    assert state.converged and state.reaction_forces.shape == (len(nodes), 3)
    weight = 9.8 * m.node_masses.sum()
    assert state.reaction_forces[: len(bottom), 2].sum() == pytest.approx(weight, rel=1e-8)
    rollers = np.flatnonzero(bottom != corner[0])
    assert np.all(state.reaction_forces[rollers, :2] == 0.0)
    assert np.array_equal(state.reaction_forces[-1], state.reaction_forces[-2])


def test_the_quasi_newton_corrector_finds_the_equilibrium_plain_newton_finds():
    m = flap()
    start = m.solve(lifted(m, 0.003))
    quasi = m.solve(lifted(m, 0.008, -0.35), initial=start)
    m.options = dataclasses.replace(m.options, max_reuse_steps=0, history=0)  # a fresh tangent at every step
    m.clear_caches()
    newton = m.solve(lifted(m, 0.008, -0.35), initial=start)
    assert quasi.converged and newton.converged
    assert quasi.data["factorizations"] < newton.data["factorizations"]
    assert newton.data["quasi_newton_steps"] == 0 < quasi.data["quasi_newton_steps"]
    assert np.abs(quasi.positions - newton.positions).max() < 1e-6 * FLAP[0]
    assert quasi.energy == pytest.approx(newton.energy, rel=1e-9)
    assert np.abs(quasi.reaction_forces - newton.reaction_forces).max() < 1e-5 * np.abs(newton.reaction_forces).max()


def test_a_solve_continues_the_diagonal_shift_of_its_start_state_and_stays_deterministic():
    """A state carries the shift its indefinite tangents needed (``tangent_shift``); a solve from it starts there.

    The kept factorisation at a start state is keyed on that shift too: the
    same positions with another shift are another start, each a function of
    its inputs alone, and both reach the same equilibrium.
    """
    m = flap()
    # one Euler predictor step: the flap buckles on its way (two steps avoid that, see the next test)
    m.options = dataclasses.replace(m.options, predictor_residual=0.0)
    start = m.solve(lifted(m, 0.004))
    assert start.data["tangent_shift"] == EquilibriumSolver.MIN_SHIFT  # nothing indefinite on the way
    target = lifted(m, 0.012, 1.2)  # the flap buckles on its way there: an indefinite tangent is shifted
    plain = m.solve(target, initial=start)
    assert plain.converged and plain.data["definite_steps"] >= 1
    assert plain.data["tangent_shift"] > EquilibriumSolver.MIN_SHIFT  # what that tangent needed
    # the same positions, another start shift (more than needed: the steps are damped more, the answer is the same)
    hint = dataclasses.replace(start, data={**start.data, "tangent_shift": 1.0})
    hinted = m.solve(target, initial=hint)
    assert hinted.converged and not _same(hinted, plain)
    again = m.solve(target, initial=start)  # not given the factorisation kept for the hinted start
    m.clear_caches()
    assert _same(plain, again) and _same(plain, m.solve(target, initial=start))
    assert _same(hinted, m.solve(target, initial=hint))
    assert np.abs(hinted.positions - plain.positions).max() < 1e-6 * FLAP[0]  # the same equilibrium
    assert hinted.energy == pytest.approx(plain.energy, rel=1e-9)


def test_a_large_motion_is_predicted_in_two_steps_and_reaches_the_same_equilibrium():
    """A predictor step that would leave a large residual is halved, the tangent factored at the midpoint."""
    m = flap()
    start = m.solve(lifted(m, 0.004))
    target = lifted(m, 0.012, 1.2)  # 8 mm up and turned by 69 degrees
    two = m.solve(target, initial=start)
    small = m.solve(lifted(m, 0.0041), initial=start)  # 0.1 mm: the linear prediction is good
    m.options = dataclasses.replace(m.options, predictor_residual=0.0)
    m.clear_caches()
    one = m.solve(target, initial=start)
    assert two.converged and one.converged and small.converged
    assert two.data["predictor_steps"] == 2 and one.data["predictor_steps"] == 1
    assert small.data["predictor_steps"] == 1
    assert two.data["definite_steps"] < one.data["definite_steps"]  # no buckling tangent on the way
    assert two.iterations < one.iterations
    assert np.abs(two.positions - one.positions).max() < 1e-6 * FLAP[0]  # the same equilibrium
    assert two.energy == pytest.approx(one.energy, rel=1e-9)
    assert np.abs(two.reaction_forces - one.reaction_forces).max() < 1e-5 * np.abs(one.reaction_forces).max()


def test_the_cubic_interpolation_finds_the_minimiser_of_a_cubic_and_of_a_quadratic():
    from surgiplan.plugins.fem.line_search import _cubic_minimiser

    # c(t) = t^3 - 3t: minimiser 1, from its values and slopes at 0 and 2 (the cubic through them is c itself)
    assert _cubic_minimiser(0.0, 0.0, -3.0, 2.0, 2.0, 9.0) == pytest.approx(1.0, abs=1e-12)
    # q(t) = (t - 0.4)^2: a cubic fit of a quadratic is the quadratic
    assert _cubic_minimiser(0.0, 0.16, -0.8, 1.0, 0.36, 1.2) == pytest.approx(0.4, abs=1e-12)
    # a cubic with no stationary point (monotone): none
    assert _cubic_minimiser(0.0, 0.0, 1.0, 1.0, 2.0, 4.0) is None  # t^3 + t


class _Quartic:
    """Π(x) = sum(x^4) / 4 - b . x along a line: the shape of a Newton step from rest on a bending beam."""

    MAX_LINE_SEARCH_TRIALS = EquilibriumSolver.MAX_LINE_SEARCH_TRIALS

    def __init__(self, b):
        self.b = np.asarray(b, dtype=float)
        self.calls = 0

    def _gradient(self, x):
        self.calls += 1
        return float(np.sum(x**4) / 4 - self.b @ x), x**3 - self.b


def test_the_line_search_lands_near_the_minimiser_along_a_quartic_and_meets_strong_wolfe():
    from types import SimpleNamespace

    from surgiplan.plugins.fem.newton import SolverOptions

    quartic = _Quartic([1.0, 2.0, -0.5])
    x = np.zeros(3)
    energy, grad = quartic._gradient(x)
    direction = 10.0 * quartic.b  # a step far past the minimiser (Π(x + d) is large and positive)
    options = SolverOptions()
    free = np.ones(3, dtype=bool)
    quartic.calls = 0
    fraction, (value, trial_grad) = EquilibriumSolver._line_search(
        quartic, x, energy, grad, direction, free, options, SimpleNamespace(line_search_cuts=0)
    )
    ts = np.linspace(0.0, 1.0, 100001)
    values = [np.sum((t * direction) ** 4) / 4 - quartic.b @ (t * direction) for t in ts]
    best = ts[int(np.argmin(values))]
    slope0, slope = float(grad @ direction), float(trial_grad @ direction)
    assert value <= energy + options.armijo * fraction * slope0  # sufficient decrease
    assert abs(slope) <= options.curvature * abs(slope0)  # the strong curvature condition
    assert fraction == pytest.approx(best, rel=0.1)  # near the minimiser (0.0675 of the step)
    assert quartic.calls <= 4  # the whole step, then a couple of cubic fits
