"""The stvk element kernel and sparse assembly: invariances, derivatives, definiteness (paper 002 §V)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial.transform import Rotation
from surgiplan.plugins.fem.assembly import TangentPattern
from surgiplan.plugins.fem.loads import BasePlane, ExternalLoads, lumped_masses, work_equivalent_masses
from surgiplan.plugins.fem.mesh import box_mesh
from surgiplan.plugins.fem.newton import EquilibriumSolver
from surgiplan.plugins.fem.stvk import StVKElements, symmetric_eigenvalues


@pytest.fixture(params=[1, 2], ids=["linear", "quadratic"])
def cube(request):
    mesh = box_mesh((0.01, 0.012, 0.008), (2, 2, 1), pattern="five", order=request.param)
    rng = np.random.default_rng(3)
    m = mesh.n_elements
    kernel = StVKElements(mesh.nodes, mesh.tets, rng.uniform(1e5, 3e5, m), rng.uniform(2e4, 6e4, m), 5e4)
    return mesh, kernel


def dense_tangent(kernel: StVKElements, x, definite=False) -> np.ndarray:
    h = kernel.evaluate(x, hessian=True, definite=definite).hessian
    size = 3 * kernel.nodes_per_element
    d = kernel.dofs.reshape(size, -1)
    m = d.shape[1]
    rows = np.broadcast_to(d[:, None, :], (size, size, m)).ravel()
    cols = np.broadcast_to(d[None, :, :], (size, size, m)).ravel()
    n = 3 * kernel.n_nodes
    return sp.coo_matrix((h.ravel(), (rows, cols)), shape=(n, n)).toarray()


def test_rigid_motion_has_no_energy_and_no_internal_force(cube):
    mesh, kernel = cube
    rotation = Rotation.from_rotvec([0.7, -1.9, 0.4]).as_matrix()
    x = mesh.nodes @ rotation.T + np.array([0.3, -0.2, 0.05])
    result = kernel.evaluate(x)
    scale = float(kernel.mu.mean() * kernel.volume.sum() / 0.01)  # force of a unit strain, N
    assert result.energy == pytest.approx(0.0, abs=1e-18)
    assert np.abs(result.gradient).max() < 1e-11 * scale
    # the six rigid modes are in the tangent's null space at rest
    k = dense_tangent(kernel, mesh.nodes)
    modes = [np.tile(e, mesh.n_nodes) for e in np.eye(3)]
    modes += [np.cross(axis, mesh.nodes).ravel() for axis in np.eye(3)]
    for mode in modes:
        assert np.abs(k @ mode).max() < 1e-9 * np.abs(k).max() * np.abs(mode).max()


def test_gradient_and_tangent_match_finite_differences(cube):
    mesh, kernel = cube
    rng = np.random.default_rng(4)
    x = mesh.nodes @ np.array([[1.1, 0.2, 0.0], [-0.1, 0.9, 0.15], [0.05, 0.0, 0.8]]).T
    x += 4e-4 / mesh.order * rng.standard_normal(x.shape)  # quadratic: nodes twice as close
    masses = nodal_masses(kernel, 1000.0)
    plane = BasePlane(np.array([0, 0, 0.003]), np.array([0.1, 0.0, 1.0]), 500.0)  # some nodes below it
    loads = ExternalLoads(mesh.nodes, masses, (0, 0, -9.8), rng.normal(0, 0.01, (mesh.n_nodes, 3)), plane)
    solver = EquilibriumSolver(kernel, loads, TangentPattern(kernel.dofs, 3 * mesh.n_nodes), 1e-3, 1e-9)
    flat = x.ravel()
    _, grad, data = solver.tangent(flat, definite=False)
    assert len(loads.evaluate(x).contact_nodes) > 0
    h = 1e-7
    fd_grad = np.array(
        [(solver.energy(flat + h * e) - solver.energy(flat - h * e)) / (2 * h) for e in np.eye(len(flat))]
    )
    assert np.abs(fd_grad - grad).max() < 1e-6 * np.abs(grad).max()
    k = solver.pattern.matrix(data).toarray()[np.ix_(solver.pattern.new_of_old, solver.pattern.new_of_old)]
    fd_k = np.column_stack(
        [(solver.gradient(flat + h * e)[1] - solver.gradient(flat - h * e)[1]) / (2 * h) for e in np.eye(len(flat))]
    )
    assert np.abs(fd_k - k).max() < 1e-6 * np.abs(k).max()
    assert np.abs(k - k.T).max() < 1e-12 * np.abs(k).max()


def test_definite_surrogate_is_positive_semidefinite_under_compression(cube):
    mesh, kernel = cube
    rng = np.random.default_rng(5)
    x = mesh.nodes * np.array([0.6, 0.7, 1.3]) + 3e-4 / mesh.order * rng.standard_normal(mesh.nodes.shape)
    exact = kernel.evaluate(x, hessian=True).hessian.copy()
    surrogate = kernel.evaluate(x, hessian=True, definite=True).hessian
    exact_low = min(np.linalg.eigvalsh(exact[:, :, e]).min() for e in range(exact.shape[2]))
    surrogate_low = min(np.linalg.eigvalsh(surrogate[:, :, e]).min() for e in range(exact.shape[2]))
    scale = np.abs(exact).max()
    assert exact_low < -1e-3 * scale  # compressed StVK is not convex: the case the surrogate is for
    assert surrogate_low > -1e-10 * scale


def test_closed_form_eigenvalues_match_lapack():
    rng = np.random.default_rng(6)
    a = rng.standard_normal((300, 3, 3))
    a = a + a.transpose(0, 2, 1)
    a[0] = np.diag([2.0, 2.0, -1.0])  # repeated eigenvalues
    a[1] = 3.0 * np.eye(3)
    low, middle, high = symmetric_eigenvalues(a.transpose(1, 2, 0))
    reference = np.linalg.eigvalsh(a)
    assert np.abs(np.column_stack([low, middle, high]) - reference).max() < 1e-7


def test_second_piola_kirchhoff_matches_the_stvk_formula(cube):
    mesh, kernel = cube
    f = np.array([[1.2, 0.1, 0.0], [0.0, 0.9, 0.2], [0.1, 0.0, 1.05]])
    s = kernel.second_piola_kirchhoff(mesh.nodes @ f.T)
    c = f.T @ f
    e = 0.5 * (c - np.eye(3))
    for k in (0, 5):
        lam, mu, kappa = kernel.lam[k], kernel.mu[k], kernel.kappa[k]
        expected = lam * np.trace(e) * np.eye(3) + 2 * mu * e + kappa * np.log(np.linalg.det(f)) * np.linalg.inv(c)
        assert np.allclose(s[k], expected, rtol=1e-12, atol=1e-9 * np.abs(expected).max())


def test_assembly_and_constrained_solve_match_dense_algebra(cube):
    mesh, kernel = cube
    rng = np.random.default_rng(7)
    x = mesh.nodes + 2e-4 * rng.standard_normal(mesh.nodes.shape)
    pattern = TangentPattern(kernel.dofs, 3 * mesh.n_nodes)
    data = pattern.assemble(kernel.evaluate(x, hessian=True).hessian)
    # assembled as the compiled kernel computes them (the Newton solve's path): the same sums
    for definite in (False, True):
        fused = kernel.evaluate(x, hessian=True, definite=definite, element_map=pattern.element_map, nnz=pattern.nnz)
        reference = pattern.assemble(kernel.evaluate(x, hessian=True, definite=definite).hessian)
        assert fused.hessian is None
        assert np.abs(fused.assembled - reference).max() <= 1e-14 * np.abs(reference).max()
    dense = dense_tangent(kernel, x)
    v = rng.standard_normal(3 * mesh.n_nodes)
    assert np.allclose(pattern.matvec(data, v), dense @ v, rtol=1e-12, atol=1e-12 * np.abs(dense @ v).max())
    prescribed = np.zeros(3 * mesh.n_nodes, dtype=bool)
    prescribed[: 3 * 9] = True  # the nodes of the face z = 0
    b = rng.standard_normal(3 * mesh.n_nodes)
    b[prescribed] = 0.0
    solution = pattern.factorize(pattern.constrain(data, prescribed)).solve(b)
    free = ~prescribed
    reference = np.linalg.solve(dense[np.ix_(free, free)], b[free])
    assert np.allclose(solution[free], reference, rtol=1e-9, atol=1e-9 * np.abs(reference).max())
    assert np.all(solution[prescribed] == 0.0)


def nodal_masses(kernel, density):
    rho = np.full(kernel.n_elements, density)
    weights = [p.weight for p in kernel.points]
    values = kernel.reference.values(kernel.reference.points)
    return work_equivalent_masses(kernel.n_nodes, kernel.tets, weights, values, rho)


def test_nodal_masses_carry_the_whole_mass(cube):
    mesh, kernel = cube
    masses = nodal_masses(kernel, 1000.0)
    assert masses.sum() == pytest.approx(1000.0 * 0.01 * 0.012 * 0.008, rel=1e-12)
    if mesh.order == 1:  # lumped: a quarter of each element's mass to each of its nodes
        lumped = lumped_masses(mesh.n_nodes, mesh.tets, kernel.volume, np.full(mesh.n_elements, 1000.0))
        assert np.allclose(masses, lumped, rtol=1e-12)
        assert np.all(masses > 0)


def test_quadratic_work_equivalent_loads_are_the_analytic_shares():
    # one straight-sided 10-node tetrahedron: int N dV is -V/20 at each vertex and V/5 at each mid-edge node
    mesh = box_mesh((0.01, 0.01, 0.01), (1, 1, 1), pattern="six", order=2)
    kernel = StVKElements(mesh.nodes, mesh.tets[:1], 1.0, 1.0, 0.0)
    used = np.unique(mesh.tets[0])
    masses = nodal_masses(kernel, 1.0)
    volume = kernel.volume[0]
    assert volume == pytest.approx(1e-6 / 6, rel=1e-12)
    assert np.allclose(masses[mesh.tets[0, :4]], -volume / 20, rtol=1e-12)
    assert np.allclose(masses[mesh.tets[0, 4:]], volume / 5, rtol=1e-12)
    assert np.count_nonzero(masses) == len(used) == 10


def test_compiled_energy_and_forces_match_the_numpy_kernel_from_positions(cube):
    """The Newton solve's energy and forces (compiled, from the displacements) against the numpy path that
    computes F from the positions: the same numbers to rounding, and the same verdict on inverted elements."""
    mesh, kernel = cube
    rng = np.random.default_rng(7)
    x = mesh.nodes @ np.array([[1.05, 0.1, 0.0], [-0.05, 0.95, 0.1], [0.02, 0.0, 0.9]]).T
    x += 2e-4 / mesh.order * rng.standard_normal(x.shape)
    u = (x - mesh.nodes).ravel()
    compiled = kernel.evaluate(u, displacement=True)
    reference = kernel.evaluate(x)  # numpy, from the positions
    assert compiled.valid and reference.valid
    assert compiled.energy == pytest.approx(reference.energy, rel=1e-12)
    assert np.abs(compiled.gradient - reference.gradient).max() < 1e-11 * np.abs(reference.gradient).max()
    assert kernel.evaluate(u, gradient=False, displacement=True).energy == compiled.energy
    # one node pushed through the opposite face inverts its elements: both paths refuse the state
    crushed = x.copy()
    corner = int(np.argmax(mesh.nodes[:, 2] + mesh.nodes[:, 0]))
    crushed[corner, 2] -= 3 * mesh.nodes[:, 2].max()
    assert not kernel.evaluate((crushed - mesh.nodes).ravel(), displacement=True).valid
    assert not kernel.evaluate(crushed).valid
    assert kernel.evaluate((crushed - mesh.nodes).ravel(), displacement=True).energy == np.inf


@pytest.mark.parametrize("definite", [False, True], ids=["exact", "surrogate"])
def test_compiled_assembled_tangent_matches_the_numpy_kernel_and_finite_differences(cube, definite):
    """The Newton solve's tangent (energy, forces and the assembled tangent in one compiled pass over the
    elements, from the displacements) against the numpy kernel's element matrices assembled by ``np.bincount``
    and, for the exact tangent, against central differences of the forces."""
    mesh, kernel = cube
    rng = np.random.default_rng(8)
    # compressed along x: the stress has a negative principal value, where the surrogate differs from the exact
    x = mesh.nodes @ np.array([[0.7, 0.1, 0.0], [-0.05, 1.1, 0.1], [0.02, 0.0, 1.2]]).T
    x += 2e-4 / mesh.order * rng.standard_normal(x.shape)
    u = (x - mesh.nodes).ravel()
    pattern = TangentPattern(kernel.dofs, 3 * mesh.n_nodes)
    compiled = kernel.evaluate(
        u, hessian=True, definite=definite, displacement=True, element_map=pattern.element_map, nnz=pattern.nnz
    )
    reference = kernel.evaluate(x, hessian=True, definite=definite)
    element_matrices = reference.hessian.copy()  # a work buffer: the next evaluation overwrites it
    assembled = pattern.assemble(element_matrices)
    assert compiled.valid and compiled.hessian is None
    assert np.abs(compiled.assembled - assembled).max() < 1e-12 * np.abs(assembled).max()
    assert compiled.energy == pytest.approx(reference.energy, rel=1e-12)
    assert np.abs(compiled.gradient - reference.gradient).max() < 1e-11 * np.abs(reference.gradient).max()
    exact = kernel.evaluate(x, hessian=True).hessian
    differs = np.abs(element_matrices - exact).max() > 1e-3 * np.abs(exact).max()
    assert differs == definite  # the state exercises the surrogate's shift
    if not definite:
        h = 1e-9
        k = pattern.matrix(compiled.assembled).toarray()[np.ix_(pattern.new_of_old, pattern.new_of_old)]
        columns = rng.choice(len(u), 12, replace=False)
        for c in columns:
            step = np.zeros_like(u)
            step[c] = h
            fd = (
                kernel.evaluate(u + step, displacement=True).gradient
                - kernel.evaluate(u - step, displacement=True).gradient
            ) / (2 * h)
            assert np.abs(fd - k[:, c]).max() < 1e-5 * np.abs(k).max()
    # an inverted element: no tangent, the state is refused
    crushed = x.copy()
    corner = int(np.argmax(mesh.nodes[:, 2] + mesh.nodes[:, 0]))
    crushed[corner, 2] -= 3 * mesh.nodes[:, 2].max()
    refused = kernel.evaluate(
        (crushed - mesh.nodes).ravel(),
        hessian=True,
        displacement=True,
        element_map=pattern.element_map,
        nnz=pattern.nnz,
    )
    assert not refused.valid and refused.energy == np.inf and refused.assembled is None


def test_compiled_state_summary_matches_the_numpy_methods(cube):
    """A solved state's volume ratios, largest principal stresses and elastic energy in one compiled pass,
    against :meth:`volume_ratio`, :meth:`max_principal_stress` and the numpy energy; inverted and
    not-a-number states included (and the compiled all-upright check agrees with the ratios)."""
    mesh, kernel = cube
    rng = np.random.default_rng(9)
    x = mesh.nodes @ np.array([[0.8, 0.1, 0.0], [-0.05, 1.1, 0.1], [0.02, 0.0, 1.15]]).T
    x += 2e-4 / mesh.order * rng.standard_normal(x.shape)
    ratio, stress, energy = kernel.summary(x)
    assert np.array_equal(ratio, kernel.volume_ratio(x))
    reference = kernel.max_principal_stress(x)
    assert np.abs(stress - reference).max() <= 1e-12 * reference.max()
    assert energy == pytest.approx(kernel.evaluate(x, gradient=False).energy, rel=1e-13)
    crushed = x.copy()
    corner = int(np.argmax(mesh.nodes[:, 2] + mesh.nodes[:, 0]))
    crushed[corner, 2] -= 3 * mesh.nodes[:, 2].max()
    ratio, _, energy = kernel.summary(crushed)
    assert np.array_equal(ratio, kernel.volume_ratio(crushed)) and ratio.min() < 0 and energy == np.inf
    broken = x.copy()
    broken[corner] = np.nan
    ratio, _, energy = kernel.summary(broken)
    assert np.array_equal(np.isnan(ratio), np.isnan(kernel.volume_ratio(broken))) and np.isnan(ratio).any()
    assert not energy < np.inf
    assert kernel.upright(x) and not kernel.upright(crushed) and not kernel.upright(broken)
