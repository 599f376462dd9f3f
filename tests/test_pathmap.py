"""The segmented pathmap: segmentation, common-segment detection, reconstruction, sizes (paper 001 Table 1)."""

from __future__ import annotations

import csv
import os

import numpy as np
import pytest
from helpers import coal_scene_segment_distance
from surgiplan.plugins.planners.optmis.repository import Repository
from surgiplan.plugins.planners.segmented_astar.graph import pathmap_edges
from surgiplan.plugins.planners.segmented_astar.pathmap import (
    _candidate_pairs,
    build_pathmap,
    reconstruction_error,
    segment_instances,
)
from surgiplan.plugins.planners.segmented_astar.report import table1, write_report
from test_optmis_support import TIP_RADIUS, offline, small_world, space

W_TIP = 2 * TIP_RADIUS


@pytest.mark.parametrize("alignment", ["path", "corners"])
@pytest.mark.parametrize("n_s", [2, 3, 4, 5])
def test_every_path_is_rebuilt_within_w_tip(n_s, alignment):
    repository = offline().repository
    pathmap = build_pathmap(repository, space(), n_s=n_s, alignment=alignment)
    error = reconstruction_error(repository, pathmap)
    assert error.max() <= W_TIP + 1e-15
    # rebuilt one by one (not vectorised) they are the same, and start and end at their points exactly
    for k in range(0, repository.n_paths, 5):
        rebuilt = pathmap.path(k)
        original = repository.path(k)
        assert rebuilt.shape == original.shape
        assert np.linalg.norm(rebuilt - original, axis=1).max() <= W_TIP + 1e-15
        np.testing.assert_array_equal(rebuilt[0], original[0])
        np.testing.assert_array_equal(rebuilt[-1], original[-1])
    assert pathmap.stats["m"] > 1.0
    assert pathmap.stats["pathmap_points"] < len(repository.points)


def test_segments_have_n_s_points_except_at_path_ends():
    repository = offline().repository
    first, count, path_of = segment_instances(repository, 3, "path")
    assert count.sum() == len(repository.points)
    assert np.all(count <= 3)
    last_of_path = np.concatenate([path_of[1:] != path_of[:-1], [True]])
    assert np.all(count[~last_of_path] == 3)  # only a path's last segment may be shorter (paper 001 §4.2)
    expected = np.diff(repository.path_start) % 3
    np.testing.assert_array_equal(count[last_of_path], np.where(expected == 0, 3, expected))
    # aligned at corners: segments restart at every turn of the taut path
    first, count, _ = segment_instances(repository, 3, "corners")
    assert count.sum() == len(repository.points)
    starts = np.zeros(len(repository.points), dtype=bool)
    starts[first] = True
    ends = np.zeros(len(repository.points), dtype=bool)
    ends[repository.path_start[1:] - 1] = True
    assert np.all(starts[repository.corner & ~ends])


def test_kd_tree_detection_finds_exactly_the_brute_force_matches():
    repository = offline().repository
    first, count, _ = segment_instances(repository, 3, "path")
    labels = np.full((len(first), 2), -1.0)
    tolerance = 1.5 * W_TIP
    found = _candidate_pairs(repository.points, first, count, labels, tolerance, reverse=True)
    found = {tuple(row) for row in found.tolist()}
    # brute force over every pair of segments of equal length, both orientations
    expected = set()
    points = [repository.points[f : f + c] for f, c in zip(first, count, strict=True)]
    for a in range(len(first)):
        for b in range(a + 1, len(first)):
            if count[a] != count[b]:
                continue
            for reverse in (0, 1):
                other = points[b][::-1] if reverse else points[b]
                if np.all(np.linalg.norm(points[a] - other, axis=1) <= tolerance):
                    expected.add((a, b, reverse))
    assert found == expected
    assert len(expected) >= 20


def test_rebuilt_paths_and_every_motion_of_the_online_graph_are_collision_free_by_coal():
    repository = offline().repository
    scene = small_world()
    # a generous tolerance makes many merges near obstacles, so junction certification has work to do
    pathmap = build_pathmap(repository, space(), n_s=3, tolerance=4 * W_TIP)
    assert pathmap.stats["unmerged_for_junctions"] > 0
    rebuilt, offsets = pathmap.reconstruct_all()
    same_path = np.ones(len(rebuilt) - 1, dtype=bool)
    same_path[offsets[1:-1] - 1] = False
    a, b = rebuilt[:-1][same_path], rebuilt[1:][same_path]
    moving = np.any(a != b, axis=1)
    assert coal_scene_segment_distance(scene, a[moving], b[moving], TIP_RADIUS).min() > 0
    points, edges, _ = pathmap_edges(pathmap)
    assert coal_scene_segment_distance(scene, points[edges[:, 0]], points[edges[:, 1]], TIP_RADIUS).min() > 0


def test_identical_paths_are_stored_once():
    # two copies of every path (as if each pair were stored twice): the pathmap holds one copy
    repository = offline().repository
    twice = Repository(
        repository.names,
        repository.pois,
        np.concatenate([repository.pairs, repository.pairs]),
        np.concatenate([repository.path_start, repository.path_start[1:] + repository.path_start[-1]]),
        np.concatenate([repository.points, repository.points]),
        np.concatenate([repository.corner, repository.corner]),
        *(
            np.concatenate([getattr(repository, n), getattr(repository, n)])
            for n in ("graph_length", "taut_length", "length", "kinds")
        ),
        repository.unreachable,
    )
    once = build_pathmap(repository, space(), n_s=3, tolerance=0.0)
    doubled = build_pathmap(twice, space(), n_s=3, tolerance=0.0)
    assert doubled.n_segments == once.n_segments
    assert doubled.stats["m"] == pytest.approx(2 * once.stats["m"])
    assert reconstruction_error(twice, doubled).max() == 0.0


def test_table1_report_sizes_are_the_bytes_on_disk(tmp_path):
    repository = offline().repository
    rows = table1(repository, space(), sizes=(2, 3, 4, 5), directory=tmp_path)
    files = write_report(tmp_path, rows, "small world")
    assert [f.name for f in files] == ["table1.csv", "table1.png"]
    with open(tmp_path / "table1.csv", newline="") as handle:
        table = list(csv.DictReader(handle))
    assert [(r["method"], int(r["n_s"])) for r in table] == [
        (method, n) for method in ("paper", "corners+reverse") for n in (2, 3, 4, 5)
    ]
    raw_bytes = os.path.getsize(tmp_path / "repository.npz")
    for row in table:
        pathmap_bytes = os.path.getsize(tmp_path / f"pathmap_{row['method']}_ns{row['n_s']}.npz")
        assert float(row["pathmap_kb"]) == pytest.approx(pathmap_bytes / 1e3, abs=0.05)
        assert float(row["raw_kb"]) == pytest.approx(raw_bytes / 1e3, abs=0.05)
        assert float(row["m_bytes"]) == pytest.approx(raw_bytes / pathmap_bytes, rel=1e-3)
        assert float(row["max_error_mm"]) <= W_TIP * 1e3 + 1e-9
        # m of eq. (1), recomputed from the stored file: points in P over points in S
        with np.load(tmp_path / f"pathmap_{row['method']}_ns{row['n_s']}.npz") as stored:
            stored_points = len(stored["segment_points"])
        assert float(row["m"]) == pytest.approx(len(repository.points) / stored_points, rel=1e-3)
        assert int(row["common_segments"]) + int(row["unique_segments"]) == int(row["stored_segments"])
        assert row["paper_pathmap_kb"] == {"2": "266", "3": "419", "4": "540", "5": "614"}[row["n_s"]]
    png = (tmp_path / "table1.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000


def test_artifact_round_trip_keeps_the_pathmap():
    from surgiplan.plugins.planners.segmented_astar.pathmap import SegmentedPathmap
    from surgiplan.storage import to_jsonable

    repository = offline().repository
    pathmap = build_pathmap(repository, space(), n_s=3)
    data = pathmap.to_artifact()
    arrays = {k: v for k, v in data.items() if isinstance(v, np.ndarray)}
    values = to_jsonable({k: v for k, v in data.items() if not isinstance(v, np.ndarray)})
    loaded = SegmentedPathmap.from_artifact({**values, **arrays})
    np.testing.assert_array_equal(loaded.reconstruct_all()[0], pathmap.reconstruct_all()[0])
    assert loaded.stats["m"] == pathmap.stats["m"]
    broken = {**values, **arrays, "path_segments": arrays["path_segments"] + 10_000}
    with pytest.raises(ValueError, match="segment reference out of range"):
        SegmentedPathmap.from_artifact(broken)


@pytest.mark.parametrize("n_s", [3, 5])
def test_thinned_encoding_keeps_every_path_within_w_tip_and_stores_far_fewer_points(n_s):
    """Douglas-Peucker (certified chords) then common segments within w_tip - thinning."""
    from scipy.spatial import cKDTree

    repository = offline().repository
    thinning = 0.25 * W_TIP
    plain = build_pathmap(repository, space(), n_s=n_s)
    pathmap = build_pathmap(repository, space(), n_s=n_s, thinning=thinning)
    assert pathmap.tolerance == pytest.approx(W_TIP - thinning)
    assert pathmap.stats["m"] > 2 * plain.stats["m"] and pathmap.stats["m_bytes"] > plain.stats["m_bytes"]
    assert pathmap.stats["repository_points"] == len(repository.points)
    error = reconstruction_error(repository, pathmap)
    assert error.max() <= W_TIP + 1e-12
    scene = small_world()
    for k in range(0, repository.n_paths, 3):
        rebuilt, original = pathmap.path(k), repository.path(k)
        np.testing.assert_array_equal(rebuilt[[0, -1]], original[[0, -1]])
        # independently: the rebuilt path sampled every 20 um, nearest sample to each original point, and back
        steps = np.linalg.norm(np.diff(rebuilt, axis=0), axis=1)
        dense = np.concatenate(
            [
                np.linspace(a, b, max(int(np.ceil(s / 2e-5)), 1), endpoint=False)
                for a, b, s in zip(rebuilt[:-1], rebuilt[1:], steps, strict=True)
            ]
            + [rebuilt[-1:]]
        )
        assert cKDTree(dense).query(original)[0].max() <= W_TIP + 2e-5
        assert error[k] >= cKDTree(dense).query(original)[0].max() - 2e-5
        moving = np.any(rebuilt[1:] != rebuilt[:-1], axis=1)
        assert coal_scene_segment_distance(scene, rebuilt[:-1][moving], rebuilt[1:][moving], TIP_RADIUS).min() > 0


def test_thinning_beyond_w_tip_is_a_clear_error():
    with pytest.raises(ValueError, match=r"thinning \(0.5 mm\) must not exceed w_tip \(0.4 mm\)"):
        build_pathmap(offline().repository, space(), thinning=0.5e-3)
