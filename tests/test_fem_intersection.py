"""Self-intersection of the deformed surface, checked against coal's triangle-triangle collision."""

from __future__ import annotations

import coal
import numpy as np
from fem_support import model
from surgiplan.plugins.fem.intersection import candidate_pairs, self_intersections
from surgiplan.plugins.fem.mesh import box_mesh

PLATE = (0.03, 0.01, 0.001)


def rolled(nodes, turn: float) -> np.ndarray:
    """The plate with its part beyond x = 0.01 rolled up around a cylinder by ``turn`` (radians).

    The bottom surface keeps its length (radius R = 0.02 / turn); past about 1.9 pi the
    rolled end comes back down through the flat part.
    """
    x = nodes.copy()
    if turn == 0:
        return x
    radius = 0.02 / turn
    s = x[:, 0] - 0.01
    rolled = s > 0
    phi = s[rolled] / radius
    r = radius - x[rolled, 2]
    x[rolled, 0] = 0.01 + r * np.sin(phi)
    x[rolled, 2] = radius - r * np.cos(phi)
    x[rolled, 1] += 3.1e-4 * np.sin(phi) ** 2  # off the grid lines: no exactly touching or coplanar pairs
    return x


def coal_crossings(x, triangles) -> set[tuple[int, int]]:
    """Vertex-disjoint triangle pairs that coal says collide (brute force over all pairs)."""
    shapes = [coal.TriangleP(*x[t]) for t in triangles]
    identity = coal.Transform3s()
    found = set()
    for i in range(len(triangles)):
        for j in range(i + 1, len(triangles)):
            if set(triangles[i]) & set(triangles[j]):
                continue
            result = coal.CollisionResult()
            if coal.collide(shapes[i], identity, shapes[j], identity, coal.CollisionRequest(), result):
                found.add((i, j))
    return found


def test_rolling_through_itself_is_detected_and_agrees_with_coal():
    mesh = box_mesh(PLATE, (24, 2, 1))
    triangles = mesh.surface
    for turn, crossing in ((0.0, False), (np.pi, False), (1.5 * np.pi, False), (1.95 * np.pi, True)):
        x = rolled(mesh.nodes, turn)
        pairs = self_intersections(x, triangles)
        assert (len(pairs) > 0) == crossing
        ours = {tuple(sorted(p)) for p in pairs.tolist() if not set(triangles[p[0]]) & set(triangles[p[1]])}
        assert ours == coal_crossings(x, triangles)


def test_candidate_pairs_are_exactly_the_overlapping_boxes():
    rng = np.random.default_rng(2)
    lower = rng.uniform(0, 1, (300, 3)) * [1, 1, 0.1]
    upper = lower + rng.uniform(0, 0.08, (300, 3))
    pairs = candidate_pairs(lower, upper)
    overlap = np.all((lower[:, None] <= upper[None]) & (lower[None] <= upper[:, None]), axis=2)
    i, j = np.triu_indices(300, 1)
    expected = set(zip(i[overlap[i, j]].tolist(), j[overlap[i, j]].tolist(), strict=True))
    assert {tuple(sorted(p)) for p in pairs.tolist()} == expected
    assert len(pairs) == len(expected)  # no duplicates
    assert np.all(pairs[:, 0] < pairs[:, 1])
    for count in (0, 1):
        assert candidate_pairs(lower[:count], upper[:count]).shape == (0, 2)
    flat = candidate_pairs(lower * [1, 1, 0], upper * [1, 1, 0])  # boxes of no thickness along z still overlap
    assert {tuple(p) for p in flat.tolist()} >= expected


def test_a_state_that_passes_through_itself_is_invalid():
    m = model(PLATE, (24, 2, 1), gravity=[0, 0, 0])
    crossing = m.evaluate_state(rolled(m.rest_nodes, 1.95 * np.pi))
    assert crossing.data["inverted_elements"] == 0
    assert not crossing.valid and crossing.data["self_intersections"] > 0
    assert "crosses itself" in crossing.message
    assert m.evaluate_state(rolled(m.rest_nodes, 1.5 * np.pi)).valid


def test_the_neighbour_prefilter_finds_exactly_what_the_direct_method_finds():
    """Vertex-sharing pairs decided by a plane-side test first (fast path, compiled and in numpy) against every
    box-overlap candidate classified and tested directly: the same crossing pairs, on plates rolled through
    themselves and on randomly perturbed (folded, crossing) flaps."""
    from surgiplan.plugins.fem.intersection import _self_intersections_reference, self_intersections_numpy

    def same(x, triangles):
        fast = self_intersections(x, triangles)  # compiled
        direct = _self_intersections_reference(x, triangles)
        direct = direct[np.lexsort((direct[:, 1], direct[:, 0]))] if len(direct) else direct.reshape(0, 2)
        assert np.array_equal(fast, direct)
        assert np.array_equal(fast, self_intersections_numpy(x, triangles))  # the same method in numpy
        return len(fast)

    mesh = box_mesh(PLATE, (24, 4, 2))
    counts = [same(rolled(mesh.nodes, turn), mesh.surface) for turn in np.linspace(0, 2.3 * np.pi, 12)]
    assert counts[0] == 0 and counts[-1] > 0
    rng = np.random.default_rng(5)
    flap = box_mesh((0.02, 0.02, 0.002), (8, 8, 2), (0, 0, 0), "five")
    noisy = [same(flap.nodes + rng.normal(scale=s, size=flap.nodes.shape), flap.surface) for s in (1e-4, 1e-3, 3e-3)]
    assert noisy[0] == 0 and noisy[-1] > 0
