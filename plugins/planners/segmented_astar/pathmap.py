"""The segmented pathmap: a path repository stored as shared segments (paper 001 §3.2, §4).

Each path of the repository P is split into segments of ``n_s`` points
(paper 001 §4.1; the last one of a path may be shorter). Two segments are
*common* when they have the same number of points and every point of one
lies within the tolerance ``w_tip`` of the matching point of the other
(paper 001 §6 matches the segment end points within w_tip; we require it of
every point, so that any path rebuilt from the pathmap is within w_tip of the
original, point by point). One copy of each common segment is stored with the
unique ones; each path becomes a sequence of references to stored segments,
which are the neighbour (predecessor/successor) references of paper 001 §5.

Detection is vectorised: a KD-tree over the segments' end points (6-D,
Chebyshev radius w_tip) proposes candidate pairs, every point of each pair is
compared at once, and the representatives are chosen by a parallel greedy
maximal independent set (Luby 1986, priority: more matches first), so every
segment is within w_tip of its representative, never only of a chain of
neighbours.

Beyond the paper:

* ``alignment: corners`` restarts the segmentation at every corner of the
  taut path, so a stretch shared by several paths is cut identically in all
  of them (paper 001 §4.2 leaves the alignment problem open: with
  ``alignment: path`` two paths sharing a stretch are aligned with
  probability 1/n_s);
* ``reverse``: a segment also matches a segment traversed the other way
  (motions are reversible; a path from A to B shares stretches with paths
  ending at A);
* *certified junctions*: replacing a segment by its representative moves the
  motion that joins it to its neighbour; every such junction motion is
  certified for the tip sphere, and segments whose junction fails keep their
  own points (repeated until all pass), so paths rebuilt from the pathmap and
  the online graph built on it are collision-free, not only within w_tip.

Sizes are measured by writing the raw repository and the pathmap in the same
on-disk format (uncompressed ``.npz``: float64 coordinates, int32 references
and delimiters), see :func:`raw_arrays` and :meth:`SegmentedPathmap.to_arrays`.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree
from surgiplan.plugins.planners.optmis.repository import Repository

ALIGNMENTS = ("path", "corners")
#: separates endpoint labels in the KD-tree features: far beyond any tolerance
_LABEL_SCALE = 1e6


@dataclass
class SegmentedPathmap:
    """Stored segments and, per path, its sequence of segment references.

    ``segment_points`` (|S| points, 3) m; segment s is
    ``segment_points[segment_start[s]:segment_start[s + 1]]``.
    ``path_segments``: references, ``s`` (forward) or ``~s`` (reversed);
    path k uses ``path_segments[path_start[k]:path_start[k + 1]]`` and joins
    points of interest ``pairs[k]``. ``uses``: how many segment instances each
    stored segment stands for (common when >= 2).
    """

    names: list[str]
    pois: np.ndarray
    pairs: np.ndarray
    segment_points: np.ndarray
    segment_start: np.ndarray
    path_segments: np.ndarray
    path_start: np.ndarray
    n_s: int
    tolerance: float
    alignment: str = "corners"
    uses: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    stats: dict = field(default_factory=dict)
    #: Douglas-Peucker tolerance (m) the paths were thinned with before segmentation (0: every point kept)
    thinning: float = 0.0

    @property
    def n_segments(self) -> int:
        return len(self.segment_start) - 1

    @property
    def n_paths(self) -> int:
        return len(self.pairs)

    def segment(self, reference: int) -> np.ndarray:
        s = reference if reference >= 0 else ~reference
        points = self.segment_points[self.segment_start[s] : self.segment_start[s + 1]]
        return points if reference >= 0 else points[::-1]

    def path(self, k: int) -> np.ndarray:
        """Path k rebuilt from its segment references."""
        refs = self.path_segments[self.path_start[k] : self.path_start[k + 1]]
        return np.concatenate([self.segment(int(r)) for r in refs])

    def reconstruct_all(self) -> tuple[np.ndarray, np.ndarray]:
        """All paths rebuilt at once: concatenated points and offsets (vectorised)."""
        refs = self.path_segments
        ids = np.where(refs >= 0, refs, ~refs)
        counts = np.diff(self.segment_start)[ids]
        owner = np.repeat(np.arange(len(refs)), counts)
        offset = np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts)
        forward = refs[owner] >= 0
        index = self.segment_start[ids[owner]] + np.where(forward, offset, counts[owner] - 1 - offset)
        path_points = np.add.reduceat(counts, self.path_start[:-1]) if len(refs) else np.zeros(0, np.int64)
        return self.segment_points[index], np.concatenate([[0], np.cumsum(path_points)])

    # ------------------------------------------------------------------ storage
    def to_arrays(self) -> dict:
        """The pathmap in the comparison format: float64 coordinates, int32 references and delimiters."""
        return {
            "segment_points": np.ascontiguousarray(self.segment_points, dtype=np.float64),
            "segment_start": self.segment_start.astype(np.int32),
            "path_segments": self.path_segments.astype(np.int32),
            "path_start": self.path_start.astype(np.int32),
            "pairs": self.pairs.astype(np.int32),
        }

    def to_artifact(self) -> dict:
        return {
            **self.to_arrays(),
            "uses": self.uses.astype(np.int32),
            "pois": self.pois,
            "poi_names": json.dumps(self.names),
            "n_s": int(self.n_s),
            "tolerance": float(self.tolerance),
            "alignment": self.alignment,
            "pathmap_stats": json.dumps(self.stats),
            "thinning": float(self.thinning),
        }

    @classmethod
    def from_artifact(cls, data) -> SegmentedPathmap:
        pathmap = cls(
            json.loads(str(data["poi_names"])),
            np.asarray(data["pois"], float).reshape(-1, 3),
            np.asarray(data["pairs"], np.int64).reshape(-1, 2),
            np.asarray(data["segment_points"], float).reshape(-1, 3),
            np.asarray(data["segment_start"], np.int64),
            np.asarray(data["path_segments"], np.int64),
            np.asarray(data["path_start"], np.int64),
            int(data["n_s"]),
            float(data["tolerance"]),
            str(data["alignment"]),
            np.asarray(data["uses"], np.int64),
            json.loads(str(data.get("pathmap_stats", "{}"))),
            float(data.get("thinning", 0.0)),
        )
        pathmap.validate()
        return pathmap

    def validate(self) -> None:
        s = self.n_segments
        if self.segment_start[0] != 0 or self.segment_start[-1] != len(self.segment_points):
            raise ValueError("segment offsets do not match the points")
        if np.any(np.diff(self.segment_start) < 1):
            raise ValueError("empty segment")
        if len(self.path_start) != self.n_paths + 1 or self.path_start[-1] != len(self.path_segments):
            raise ValueError("path offsets do not match the references")
        ids = np.where(self.path_segments >= 0, self.path_segments, ~self.path_segments)
        if len(ids) and (ids.min() < 0 or ids.max() >= s):
            raise ValueError("segment reference out of range")
        if len(self.uses) != s:
            raise ValueError("segment use counts do not match the segments")


# ----------------------------------------------------------------------------- segmentation


def segment_instances(repository: Repository, n_s: int, alignment: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split every path into segments of ``n_s`` points: per instance its first point, point count and path."""
    if alignment not in ALIGNMENTS:
        raise ValueError(f"unknown alignment '{alignment}'; choose one of: {', '.join(ALIGNMENTS)}")
    total = len(repository.points)
    starts = repository.path_start[:-1]
    path_of = np.repeat(np.arange(repository.n_paths), np.diff(repository.path_start))
    anchor = np.zeros(total, dtype=bool)
    anchor[starts] = True
    if alignment == "corners":
        last = np.zeros(total, dtype=bool)
        last[repository.path_start[1:] - 1] = True
        anchor |= repository.corner & ~last  # a path's last point does not start a segment of its own
    index = np.arange(total)
    last_anchor = np.maximum.accumulate(np.where(anchor, index, 0))
    begins = anchor | ((index - last_anchor) % n_s == 0)
    first = np.flatnonzero(begins)
    count = np.diff(np.concatenate([first, [total]]))
    return first, count, path_of[first]


def _candidate_pairs(points, first, count, labels, tolerance, reverse) -> np.ndarray:
    """Instance pairs (a, b, reversed) whose matching points are all within ``tolerance``, a < b."""
    found = []
    for c in np.unique(count):
        members = np.flatnonzero(count == c)
        if len(members) < 2:
            continue
        head = points[first[members]]
        tail = points[first[members] + c - 1]
        rows = [np.hstack([head, tail, labels[members] * _LABEL_SCALE])]
        owner, flipped = [members], [np.zeros(len(members), dtype=bool)]
        if reverse:
            rows.append(np.hstack([tail, head, labels[members][:, ::-1] * _LABEL_SCALE]))
            owner.append(members)
            flipped.append(np.ones(len(members), dtype=bool))
        features = np.concatenate(rows)
        owner = np.concatenate(owner)
        flipped = np.concatenate(flipped)
        pairs = cKDTree(features).query_pairs(tolerance, p=np.inf, output_type="ndarray")
        if not len(pairs):
            continue
        a, b = owner[pairs[:, 0]], owner[pairs[:, 1]]
        rev = flipped[pairs[:, 0]] ^ flipped[pairs[:, 1]]
        keep = a != b
        a, b, rev = a[keep], b[keep], rev[keep]
        a, b = np.minimum(a, b), np.maximum(a, b)
        key = np.unique((a * len(first) + b) * 2 + rev)
        rev = (key % 2).astype(bool)
        a, b = (key // 2) // len(first), (key // 2) % len(first)
        # every point of a against the matching point of b
        k = np.arange(c)
        pa = points[first[a][:, None] + k]
        pb = points[first[b][:, None] + np.where(rev[:, None], c - 1 - k, k)]
        close = np.all(np.linalg.norm(pa - pb, axis=2) <= tolerance, axis=1)
        found.append(np.stack([a[close], b[close], rev[close].astype(np.int64)], axis=1))
    return np.concatenate(found) if found else np.zeros((0, 3), dtype=np.int64)


def choose_representatives(n: int, pairs: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A representative for each of ``n`` instances, every one within tolerance of its own.

    Parallel greedy maximal independent set (Luby 1986) on the match graph:
    in each round the undecided instances that outrank all their undecided
    neighbours (more matches first, ties broken by a seeded random order)
    become representatives and take their undecided neighbours. Returns the
    representative of each instance and whether it is used reversed.
    """
    rep = np.full(n, -1, dtype=np.int64)
    flip = np.zeros(n, dtype=bool)
    if not len(pairs):
        rep[:] = np.arange(n)
        return rep, flip
    a, b, r = pairs[:, 0], pairs[:, 1], pairs[:, 2].astype(bool)
    degree = np.bincount(np.concatenate([a, b]), minlength=n)
    noise = np.random.default_rng(seed).permutation(n)
    rank = np.empty(n, dtype=np.int64)
    rank[np.lexsort((noise, -degree))] = np.arange(n)  # 0 is the strongest
    src = np.concatenate([a, b])
    dst = np.concatenate([b, a])
    rev = np.concatenate([r, r])
    while np.any(rep < 0):
        open_edge = (rep[src] < 0) & (rep[dst] < 0)
        best_neighbour = np.full(n, n, dtype=np.int64)
        np.minimum.at(best_neighbour, src[open_edge], rank[dst[open_edge]])
        leaders = np.flatnonzero((rep < 0) & (rank < best_neighbour))
        rep[leaders] = leaders
        # undecided neighbours of the new leaders join the strongest of them
        join = open_edge & (rep[dst] == dst) & np.isin(dst, leaders) & (rep[src] < 0)
        s, d, v = src[join], dst[join], rev[join]
        order = np.lexsort((rank[d], s))
        s, d, v = s[order], d[order], v[order]
        first = np.concatenate([[True], s[1:] != s[:-1]]) if len(s) else np.zeros(0, dtype=bool)
        rep[s[first]] = d[first]
        flip[s[first]] = v[first]
    return rep, flip


def _junction_motions(repository_points, first, count, rep, flip, path_of) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For consecutive instances of each path: where the motion between their representatives starts and ends."""
    follows = np.flatnonzero(path_of[1:] == path_of[:-1])  # instance i is followed by i + 1
    u, v = follows, follows + 1
    # last point of u's representative as used, first point of v's
    u_end = np.where(flip[u], first[rep[u]], first[rep[u]] + count[rep[u]] - 1)
    v_start = np.where(flip[v], first[rep[v]] + count[rep[v]] - 1, first[rep[v]])
    return u, repository_points[u_end], repository_points[v_start]


def thin_repository(repository: Repository, space, tolerance: float, margin: float = 0.0) -> Repository:
    """Every path thinned by Douglas-Peucker within ``tolerance`` (m), each kept chord certified (keeping margin).

    The corner flags of the kept points are kept; the lengths are the stored paths' (unchanged).
    """
    from dataclasses import replace

    from surgiplan.paths import thin

    points, corner, starts = [], [], [0]
    for k in range(repository.n_paths):
        a, b = repository.path_start[k], repository.path_start[k + 1]
        path = repository.points[a:b]
        if len(path) > 2:
            kept, _ = thin(space, path, np.full(len(path) - 1, margin), tolerance)
            # thin() returns rows of ``path`` in order: recover their indices
            index = np.zeros(len(kept), dtype=np.int64)
            j = 0
            for i, q in enumerate(kept):
                while not np.array_equal(path[j], q):
                    j += 1
                index[i] = j
                j += 1
        else:
            index = np.arange(len(path))
        points.append(path[index])
        corner.append(repository.corner[a:b][index])
        starts.append(starts[-1] + len(index))
    return replace(
        repository,
        points=np.concatenate(points) if points else repository.points[:0],
        corner=np.concatenate(corner) if corner else repository.corner[:0],
        path_start=np.asarray(starts, dtype=repository.path_start.dtype),
    )


def build_pathmap(
    repository: Repository,
    space,
    *,
    n_s: int = 3,
    tolerance: float | None = None,
    alignment: str = "corners",
    reverse: bool = True,
    margin: float = 0.0,
    seed: int = 0,
    thinning: float = 0.0,
) -> SegmentedPathmap:
    """The segmented pathmap of ``repository`` (paper 001 §3.2, §4.1).

    ``tolerance`` (m) defaults to w_tip, the tip sphere's diameter, less
    ``thinning``: with ``thinning`` > 0 each path is first thinned by
    Douglas-Peucker within it (certified chords), so that every original
    point lies within thinning + tolerance = w_tip of its rebuilt path.
    Junction motions are certified in ``space`` (keeping ``margin``).
    """
    if n_s < 1:
        raise ValueError("segments need at least one point")
    w_tip = 2.0 * space.tip_radius
    tolerance = w_tip - thinning if tolerance is None else float(tolerance)
    if tolerance < 0:
        raise ValueError(f"thinning ({thinning * 1e3:.3g} mm) must not exceed w_tip ({w_tip * 1e3:.3g} mm)")
    original = repository
    if thinning > 0:
        repository = thin_repository(repository, space, thinning, margin)
    points = repository.points
    first, count, path_of = segment_instances(repository, n_s, alignment)
    n = len(first)
    # endpoint labels: a segment holding a path's first (last) point matches only segments holding
    # the same point of interest there, so that paths start and end at their points exactly
    labels = np.full((n, 2), -1.0)
    path_first = repository.path_start[:-1]
    path_last = repository.path_start[1:] - 1
    starts_path = np.isin(first, path_first)
    ends_path = np.isin(first + count - 1, path_last)
    labels[starts_path, 0] = repository.pairs[path_of[starts_path], 0]
    labels[ends_path, 1] = repository.pairs[path_of[ends_path], 1]
    pairs = _candidate_pairs(points, first, count, labels, tolerance, reverse)
    rep, flip = choose_representatives(n, pairs, seed)

    # certified junctions: un-merge instances whose junction motion is not certified, until none is left
    rounds = 0
    unmerged = 0
    while True:
        u, a, b = _junction_motions(points, first, count, rep, flip, path_of)
        moved = (rep[u] != u) | (rep[u + 1] != u + 1)
        if not np.any(moved):
            break
        keys, inverse = np.unique(np.hstack([a[moved], b[moved]]), axis=0, return_inverse=True)
        ok = space.motion_is_clear(keys[:, :3], keys[:, 3:], margin)[inverse.reshape(-1)]
        bad = u[moved][~ok]
        if not bad.size:
            break
        rounds += 1
        for side in (bad, bad + 1):
            fix = side[rep[side] != side]
            unmerged += len(fix)
            rep[fix] = fix
            flip[fix] = False
    # a representative of others must stand for itself
    assert np.all(rep[rep] == rep)

    stored = np.flatnonzero(rep == np.arange(n))
    new_id = np.full(n, -1, dtype=np.int64)
    new_id[stored] = np.arange(len(stored))
    uses = np.bincount(new_id[rep], minlength=len(stored))
    seg_counts = count[stored]
    segment_start = np.concatenate([[0], np.cumsum(seg_counts)])
    owner = np.repeat(np.arange(len(stored)), seg_counts)
    offset = np.arange(len(owner)) - np.repeat(segment_start[:-1], seg_counts)
    segment_points = points[first[stored][owner] + offset]
    refs = np.where(flip, ~new_id[rep], new_id[rep])
    path_start = np.concatenate([[0], np.cumsum(np.bincount(path_of, minlength=repository.n_paths))])
    pathmap = SegmentedPathmap(
        list(repository.names),
        repository.pois.copy(),
        repository.pairs.copy(),
        segment_points,
        segment_start,
        refs,
        path_start,
        int(n_s),
        tolerance,
        alignment,
        uses,
        thinning=float(thinning),
    )
    # m and the raw file against the repository as stored (every point), whatever the encoding
    pathmap.stats = pathmap_statistics(original, pathmap)
    pathmap.stats.update(
        {
            "junction_rounds": rounds,
            "unmerged_for_junctions": int(unmerged),
            "reverse_matching": bool(reverse),
            "thinning_m": float(thinning),
            "thinned_points": len(repository.points),
            # the sharing alone: points of the thinned paths over points stored
            "m_sharing": len(repository.points) / max(len(pathmap.segment_points), 1),
        }
    )
    return pathmap


# ----------------------------------------------------------------------------- sizes (paper 001 Table 1)


def raw_arrays(repository: Repository) -> dict:
    """The raw repository in the comparison format: float64 points, int32 delimiters and pairs."""
    return {
        "points": np.ascontiguousarray(repository.points, dtype=np.float64),
        "path_start": repository.path_start.astype(np.int32),
        "pairs": repository.pairs.astype(np.int32),
    }


def npz_bytes(arrays: dict) -> int:
    """Size (bytes) of the arrays written as an uncompressed ``.npz`` file."""
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getbuffer().nbytes


def pathmap_statistics(repository: Repository, pathmap: SegmentedPathmap) -> dict:
    """Paper 001 Table 1 and eq. (1) for one pathmap (sizes in bytes, m dimensionless)."""
    counts = np.diff(pathmap.segment_start)
    common = pathmap.uses >= 2
    point_bytes = 3 * 8
    reference_bytes = 4
    common_bytes = int(counts[common].sum()) * point_bytes + int(np.count_nonzero(common)) * reference_bytes
    unique_bytes = int(counts[~common].sum()) * point_bytes + int(np.count_nonzero(~common)) * reference_bytes
    # the neighbour references (each path's segment sequence) and the path delimiters
    links_bytes = (len(pathmap.path_segments) + len(pathmap.path_start) + 2 * pathmap.n_paths) * reference_bytes
    raw_file = npz_bytes(raw_arrays(repository))
    pathmap_file = npz_bytes(pathmap.to_arrays())
    instances = len(pathmap.path_segments)
    common_instances = int(pathmap.uses[common].sum())
    return {
        "n_s": int(pathmap.n_s),
        "alignment": pathmap.alignment,
        "tolerance_m": float(pathmap.tolerance),
        "paths": int(pathmap.n_paths),
        "segment_instances": instances,
        "stored_segments": int(pathmap.n_segments),
        "common_segments": int(np.count_nonzero(common)),
        "unique_segments": int(np.count_nonzero(~common)),
        "common_instance_share": common_instances / instances if instances else 0.0,
        "repository_points": len(repository.points),
        "pathmap_points": len(pathmap.segment_points),
        "m": len(repository.points) / max(len(pathmap.segment_points), 1),
        "common_bytes": common_bytes,
        "unique_bytes": unique_bytes,
        "links_bytes": links_bytes,
        "raw_file_bytes": raw_file,
        "pathmap_file_bytes": pathmap_file,
        "m_bytes": raw_file / pathmap_file,
    }


def reconstruction_error(repository: Repository, pathmap: SegmentedPathmap) -> np.ndarray:
    """Per path, the largest distance (m) between the original and its rebuilt path.

    Point by point when every point was kept; for a thinned pathmap the
    two-sided distance between the polylines: every original point to the
    rebuilt path, and every rebuilt point to the original path.
    """
    rebuilt, offsets = pathmap.reconstruct_all()
    if pathmap.thinning > 0:
        out = np.zeros(repository.n_paths)
        for k in range(repository.n_paths):
            original = repository.points[repository.path_start[k] : repository.path_start[k + 1]]
            mine = rebuilt[offsets[k] : offsets[k + 1]]
            out[k] = max(_to_polyline(original, mine).max(), _to_polyline(mine, original).max())
        return out
    if len(rebuilt) != len(repository.points) or not np.array_equal(offsets, repository.path_start):
        raise ValueError("the pathmap does not rebuild paths of the repository's lengths")
    error = np.linalg.norm(rebuilt - repository.points, axis=1)
    return np.maximum.reduceat(error, repository.path_start[:-1]) if len(error) else np.zeros(0)


def _to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance (m) from each point to the polyline (its segments, or its one point)."""
    if len(polyline) == 1:
        return np.linalg.norm(points - polyline[0], axis=1)
    a, b = polyline[:-1][None], polyline[1:][None]  # (1, s, 3)
    d = b - a
    t = np.clip(
        np.einsum("psk,psk->ps", points[:, None] - a, d) / np.maximum(np.einsum("psk,psk->ps", d, d), 1e-300), 0, 1
    )
    return np.linalg.norm(points[:, None] - (a + t[..., None] * d), axis=2).min(axis=1)
