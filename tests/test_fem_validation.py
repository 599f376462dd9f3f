"""stvk against independent answers: analytic StVK, a patch test, the elastica, and solver behaviour."""

from __future__ import annotations

import numpy as np
import pytest
from fem_support import elastica_tip, face, model, on, uniaxial_stvk
from surgiplan.plugins.fem import AxisConstraints

SIZE = (0.02, 0.01, 0.01)


def roller_constraints(m, stretch=None):
    """Symmetry planes x = 0, y = 0, z = 0 (held along their normal), and the face x = L moved to ``stretch`` L."""
    nodes, axes, targets = [], [], []
    for axis in range(3):
        ids = on(m, face(axis, 0.0, SIZE))
        held = np.zeros((len(ids), 3), dtype=bool)
        held[:, axis] = True
        nodes.append(ids), axes.append(held), targets.append(m.rest_nodes[ids])
    if stretch is not None:
        ids = on(m, face(0, SIZE[0], SIZE))
        held = np.zeros((len(ids), 3), dtype=bool)
        held[:, 0] = True
        nodes.append(ids), axes.append(held), targets.append(m.rest_nodes[ids] * [stretch, 1, 1])
    return np.concatenate(nodes), np.concatenate(targets), np.concatenate(axes)


@pytest.mark.parametrize("volume_penalty", [0.0, 0.5])
def test_uniaxial_stretch_matches_the_analytic_stvk_answer(volume_penalty):
    e, nu, a = 1e6, 0.3, 1.3
    material = {"youngs_modulus": e, "poisson_ratio": nu, "volume_penalty": volume_penalty}
    m = model(SIZE, (2, 1, 1), material=material, gravity=[0, 0, 0], solver={"residual_tol": 1e-11})
    nodes, targets, axes = roller_constraints(m, stretch=a)
    state = m.solve(AxisConstraints(nodes, targets, None, axes))
    lam, mu = m.material.lame
    kappa = volume_penalty * (lam[0] + 2 * mu[0] / 3)
    b, nominal = uniaxial_stvk(a, e, nu, kappa)
    assert state.converged and state.valid
    f = np.linalg.lstsq(np.c_[m.rest_nodes, np.ones(m.mesh.n_nodes)], state.positions, rcond=None)[0][:3].T
    assert np.allclose(f, np.diag([a, b, b]), atol=1e-9)
    end = on(m, face(0, SIZE[0], SIZE))
    force = state.data["reaction_field"][end, 0].sum()  # N, pulled by the moving face
    assert force == pytest.approx(nominal * SIZE[1] * SIZE[2], rel=1e-8)
    assert np.allclose(state.stress, abs(nominal / a), rtol=1e-8)  # S_11 = P_11 / a; S_22 = S_33 = 0


def test_uniaxial_dead_load_gives_the_analytic_stretch():
    e, nu = 1e6, 0.45
    a = 1.15
    m = model(
        SIZE,
        (2, 1, 1),
        material={"youngs_modulus": e, "poisson_ratio": nu},
        gravity=[0, 0, 0],
        solver={"residual_tol": 1e-11},
    )
    lam, mu = m.material.lame
    _, nominal = uniaxial_stvk(a, e, nu, 0.1 * (lam[0] + 2 * mu[0] / 3))
    nodes, targets, axes = roller_constraints(m)
    end = on(m, face(0, SIZE[0], SIZE))
    # a uniform traction: each boundary triangle of the face gives a third of its share to each corner
    triangles = m.surface_triangles[np.all(np.isin(m.surface_triangles, end), axis=1)]
    corners = m.rest_nodes[triangles]
    areas = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1) / 2
    assert areas.sum() == pytest.approx(SIZE[1] * SIZE[2], rel=1e-12)
    forces = np.zeros((m.mesh.n_nodes, 3))
    np.add.at(forces[:, 0], triangles.ravel(), np.repeat(nominal * areas / 3, 3))
    state = m.solve(AxisConstraints(nodes, targets, forces, axes))
    assert state.converged
    assert state.positions[end, 0] == pytest.approx(np.full(len(end), a * SIZE[0]), rel=1e-8)


@pytest.mark.parametrize("order", [1, 2])
def test_patch_test_reproduces_an_affine_deformation_on_an_irregular_mesh(order):
    m = model(SIZE, (3, 3, 3), gravity=[0, 0, 0], solver={"residual_tol": 1e-11})
    rng = np.random.default_rng(11)
    interior = np.setdiff1d(np.arange(m.mesh.n_nodes), np.unique(m.surface_triangles))
    irregular = m.mesh.nodes.copy()
    irregular[interior] += rng.uniform(-0.2, 0.2, (len(interior), 3)) * np.array(SIZE) / 3
    mesh = type(m.mesh)(irregular, m.mesh.tets)  # same topology, distorted elements
    # quadratic: straight-sided (mid-edge nodes at the middle of the distorted edges); curved 10-node
    # tetrahedra pass the patch test only approximately under the four-point rule
    mesh = mesh.quadratic() if order == 2 else mesh
    m = type(m)(m.settings, mesh=mesh)
    boundary = np.unique(m.surface_triangles)
    interior = np.setdiff1d(np.arange(m.mesh.n_nodes), boundary)
    irregular = m.mesh.nodes
    f = np.array([[1.25, 0.1, -0.05], [0.02, 0.85, 0.1], [0.0, -0.1, 1.1]])
    exact = irregular @ f.T + [0.001, -0.002, 0.003]
    state = m.solve(m.grasp_constraints(boundary, (f, [0.001, -0.002, 0.003]), anchored=False))
    assert state.converged
    assert len(interior) > 0
    assert np.abs(state.positions - exact).max() < 1e-9 * SIZE[0]
    s = m.kernel.second_piola_kirchhoff_at_points(state.positions)
    assert np.abs(s - s[0, 0]).max() < 1e-6 * np.abs(s[0, 0]).max()  # uniform stress at every quadrature point
    e = 0.5 * (f.T @ f - np.eye(3))
    lam, mu = m.material.lame
    kappa = m.material.penalty_modulus[0]
    c_inv = np.linalg.inv(f.T @ f)
    expected = lam[0] * np.trace(e) * np.eye(3) + 2 * mu[0] * e + kappa * np.log(np.linalg.det(f)) * c_inv
    assert np.allclose(s[0, 0], expected, rtol=1e-8, atol=1e-8 * np.abs(expected).max())


def cantilever_tip(order: int, k: int, alpha: float, length=0.1, height=0.01, e=1e6, **extra) -> tuple[float, object]:
    """Tip deflection over L of a square cantilever (10k x k x k cells) under a dead tip load P = alpha EI / L^2."""
    load = alpha * e * height**4 / 12 / length**2  # N
    size = (length, height, height)
    m = model(
        size,
        (10 * k, k, k),
        mesh={"box": {"size": list(size), "divisions": [10 * k, k, k]}, "order": order},
        material={"youngs_modulus": e, "poisson_ratio": 0.0, "volume_penalty": 0.0},
        gravity=[0, 0, 0],
        anchored=[{"region": face(0, 0.0, size)}],
        loads=[{"region": face(0, length, size), "total_force": [0, 0, -load]}],
        **extra,
    )
    state = m.solve(m.stage_constraints())
    assert state.converged and state.valid
    tip = on(m, face(0, length, size))
    return -(state.positions[tip, 2] - m.rest_nodes[tip, 2]).mean() / length, state


def test_cantilever_tip_deflection_converges_to_the_elastica():
    reference, _ = elastica_tip(1.0)
    assert reference == pytest.approx(0.3017, abs=5e-4)  # Bisshopp & Drucker's table
    linear = [(reference - cantilever_tip(1, k, 1.0)[0]) / reference for k in (1, 2, 4)]
    # linear tetrahedra lock in bending: too stiff, converging from below as h -> 0
    assert all(err > 0 for err in linear)
    assert linear[0] > 1.7 * linear[1] and linear[1] > 2.5 * linear[2]
    assert linear[2] < 0.16
    # quadratic tetrahedra do not lock: the coarsest mesh is already within 1 % of the elastica, and refining
    # moves the answer by less than 0.2 %. What remains is the continuum's shear and extension, which the
    # inextensible, shear-rigid elastica leaves out (Timoshenko's shear term alone: 0.6 (h/L)^2 = +0.6 %).
    coarse, state = cantilever_tip(2, 1, 1.0)
    fine, _ = cantilever_tip(2, 2, 1.0)
    assert abs(coarse - reference) / reference < 0.01
    assert abs(fine - coarse) / fine < 0.002
    assert 0 < (fine - reference) / reference < 0.01
    assert state.data["inverted_elements"] == 0


def test_quadratic_cantilever_matches_beam_theory_in_the_small_deflection_limit():
    alpha = 1e-3  # P L^2 / EI: deflection L / 3000, linear elasticity
    deflection, _ = cantilever_tip(2, 1, alpha, solver={"residual_tol": 1e-10})
    timoshenko = alpha / 3 * (1 + 0.6 * 0.1**2)  # Euler-Bernoulli P L^3 / 3EI plus the shear term (kappa = 5/6)
    assert deflection == pytest.approx(timoshenko, rel=2e-3)


@pytest.mark.parametrize(("order", "divisions"), [(1, (8, 8, 2)), (2, (4, 4, 1))])
def test_energy_never_increases_during_a_solve(order, divisions):
    size = (0.05, 0.05, 0.0025)
    m = model(
        size,
        divisions,
        pattern="five",
        mesh={"box": {"size": list(size), "divisions": list(divisions), "pattern": "five"}, "order": order},
        material={"youngs_modulus": 2e5},
        anchored=[{"region": face(0, 0.0, size)}],
        loads=[{"region": face(0, size[0], size), "total_force": [0, 0, 0.05]}],
        base_plane={},
    )
    state = m.solve(m.stage_constraints())
    history = np.array(state.data["energy_history"])
    assert state.converged and len(history) >= 4
    assert np.all(np.diff(history) <= 1e-12 * np.abs(history).max())
    assert history[-1] == pytest.approx(state.energy, rel=1e-12)
    assert state.energy == pytest.approx(
        state.data["elastic_energy"] + state.data["contact_energy"] - state.data["external_work"]
    )


def test_stiffer_veins_deflect_less_and_softer_tissue_more():
    size = (0.04, 0.02, 0.004)
    base = {
        "anchored": [{"region": face(0, 0.0, size)}],
        "gravity": [0, 0, -9.8],
        "loads": [{"region": face(0, size[0], size), "total_force": [0, 0, -0.02]}],
    }
    vein = {"region": {"min": [0, 0.007, 0], "max": [0.04, 0.013, 0.004]}}

    def tip_drop(material):
        m = model(size, (16, 8, 2), material=material, **base)
        state = m.solve(m.stage_constraints())
        assert state.converged
        tip = on(m, face(0, size[0], size))
        return -(state.positions[tip, 2] - m.rest_nodes[tip, 2]).mean()

    tissue = tip_drop({"youngs_modulus": 2.5e5})
    veins = tip_drop({"youngs_modulus": 2.5e5, "regions": [{**vein, "youngs_modulus": 1e6}]})
    softer = tip_drop({"youngs_modulus": 2.5e5, "regions": [{**vein, "youngs_modulus": 5e4}]})
    uniform_stiff = tip_drop({"youngs_modulus": 1e6})
    assert uniform_stiff < veins < tissue < softer
    assert veins < 0.9 * tissue


def test_veins_from_a_thresholded_image_stiffen_a_strip_by_the_composite_beam_ratio(tmp_path):
    """Paper 002 §VI scenario 2: veins segmented from a thresholded image get a stiffer modulus.

    A cantilever strip 60 x 10 x 3 mm with a vein 2 mm wide along its length (a dark band on the image):
    side-by-side strips bend together, so beam theory gives deflection ratio
    E_t b / (E_t (b - w) + E_v w) = 0.625 for E_t = 250 kPa and E_v = 1 MPa (the paper's values).
    """
    import matplotlib.image

    length, width, height = 0.06, 0.01, 0.003
    size = (length, width, height)
    image = np.ones((50, 300))  # 0.2 mm pixels, top row first: rows 20-29 are y = 6 mm down to 4 mm
    image[20:30, :] = 0.1
    path = tmp_path / "veins.png"
    matplotlib.image.imsave(path, image, cmap="gray", vmin=0, vmax=1)
    image_map = {"file": str(path), "min": [0, 0], "max": [length, width], "threshold": 0.5}
    veins = {"image": image_map, "youngs_modulus": 1e6}

    def tip(regions):
        m = model(
            size,
            (12, 5, 1),
            mesh={"box": {"size": list(size), "divisions": [12, 5, 1]}, "order": 2},
            material={"youngs_modulus": 2.5e5, "poisson_ratio": 0.0, "volume_penalty": 0.0, "regions": regions},
            gravity=[0, 0, 0],
            anchored=[{"region": face(0, 0.0, size)}],
            loads=[{"region": face(0, length, size), "total_force": [0, 0, -1e-5]}],
            solver={"residual_tol": 1e-10},
        )
        state = m.solve(m.stage_constraints())
        assert state.converged
        end = on(m, face(0, length, size))
        return -(state.positions[end, 2] - m.rest_nodes[end, 2]).mean(), m

    uniform, _ = tip([])
    stiffened, m = tip([veins])
    vein = m.material.youngs_modulus == 1e6
    assert m.kernel.volume[vein].sum() / m.kernel.volume.sum() == pytest.approx(0.2, rel=1e-12)
    assert np.all(np.abs(m.mesh.centroids[vein, 1] - 0.005) < 0.001)  # the middle column of cells, nothing else
    beam = 1e-5 * length**3 / (3 * 2.5e5 * width * height**3 / 12)
    assert uniform == pytest.approx(beam, rel=3e-3)
    assert stiffened / uniform == pytest.approx(2.5e5 * width / (2.5e5 * 0.008 + 1e6 * 0.002), rel=2e-3)


def test_linear_tetrahedra_lock_in_bending_and_quadratic_ones_do_not():
    """A flap strip (50 x 10 x 2.5 mm) sagging under its own weight, against beam theory q L^4 / 8 EI."""
    length, width, height = 0.05, 0.01, 0.0025
    size = (length, width, height)
    density = 10.0  # kg/m^3: a light strip, so that the sag stays in the linear range (L / 400)
    beam = density * 9.8 * width * height * length**4 / (8 * 1e6 * width * height**3 / 12)

    def sag(divisions, order):
        m = model(
            size,
            divisions,
            pattern="five",
            mesh={"box": {"size": list(size), "divisions": list(divisions), "pattern": "five"}, "order": order},
            material={"youngs_modulus": 1e6, "poisson_ratio": 0.0, "density": density, "volume_penalty": 0.0},
            anchored=[{"region": face(0, 0.0, size)}],
        )
        state = m.solve(m.stage_constraints())
        assert state.converged
        end = on(m, face(0, length, size))
        weight = density * 9.8 * np.prod(size)
        assert state.data["reaction_field"][:, 2].sum() == pytest.approx(weight, rel=1e-6)  # the clamp carries it
        return -(state.positions[end, 2] - m.rest_nodes[end, 2]).mean() / beam

    one_layer, two_layers, four_layers = sag((20, 4, 1), 1), sag((20, 4, 2), 1), sag((40, 8, 4), 1)
    assert one_layer < 0.35 and two_layers < 0.5  # the paper's flap mesh has two layers of linear tetrahedra
    assert one_layer < two_layers < four_layers < 0.8
    assert sag((10, 2, 1), 2) == pytest.approx(1.0, abs=0.01)  # one layer of quadratic tetrahedra


def test_warm_start_reaches_the_cold_solution_in_fewer_iterations():
    size = (0.05, 0.05, 0.0025)
    m = model(size, (10, 10, 2), pattern="five", anchored=[{"region": face(0, 0.0, size)}], base_plane={})
    jaws = m.nodes_in_region([0.0475, 0.02, 0], [0.05, 0.03, 0.0025])
    previous = None
    for lift in (0.004, 0.006):
        pose = np.eye(4)
        pose[2, 3] = lift
        warm = m.solve(m.grasp_constraints(jaws, pose), initial=previous)
        previous = warm
    cold = m.solve(m.grasp_constraints(jaws, pose))
    assert warm.converged and cold.converged
    assert warm.iterations < cold.iterations
    assert np.abs(warm.positions - cold.positions).max() < 1e-6 * size[0]
    assert warm.energy == pytest.approx(cold.energy, rel=1e-6)
    assert np.allclose(warm.positions[jaws], m.rest_nodes[jaws] + [0, 0, 0.006], atol=1e-15)


def test_disp_distance_is_the_largest_surface_node_displacement():
    size = (0.02, 0.01, 0.004)
    m = model(size, (4, 2, 2))
    moved = m.rest_nodes.copy()
    inside = np.setdiff1d(np.arange(m.mesh.n_nodes), m.surface_nodes)
    assert len(inside) > 0 and len(m.surface_nodes) + len(inside) == m.mesh.n_nodes
    moved[inside] += [0.5, 0, 0]  # interior nodes do not count
    moved[m.surface_nodes[3]] += [0.003, 0.004, 0]
    assert m.disp_distance(m.rest_nodes, moved) == pytest.approx(0.005, rel=1e-12)


def test_non_convergence_is_reported_not_hidden():
    size = (0.05, 0.01, 0.01)
    m = model(
        size,
        (10, 2, 2),
        anchored=[{"region": face(0, 0.0, size)}],
        loads=[{"region": face(0, size[0], size), "total_force": [0, 0, -2.0]}],
        solver={"max_iterations": 2},
    )
    state = m.solve(m.stage_constraints())
    assert not state.converged
    assert "did not converge in 2 Newton iterations" in state.message
    assert state.residual > 0
