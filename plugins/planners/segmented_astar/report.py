"""Paper 001 Table 1 for a repository: pathmap sizes for segment sizes n_s = 2..5, as CSV and a bar chart.

For each segment size the repository is segmented, common segments are
detected within w_tip, and the sizes are measured by writing the raw
repository and each pathmap to disk in the same format (uncompressed
``.npz``: float64 coordinates, int32 references and delimiters), so the
bytes compare fairly. Two methods are reported side by side: the paper's
(segments counted from each path's start, forward matching only) and the
configured one (by default anchored at the corners of the taut paths, with
reversed matching). Paper 001's own figures are in the same table.

Columns (sizes in KB = 1000 bytes): ``common_kb`` and ``unique_kb`` (the
points of common / unique stored segments plus their offsets), ``links_kb``
(the neighbour references and path delimiters), ``pathmap_kb`` and
``raw_kb`` (the two files), ``m`` (paper 001 eq. 1: points in P over points
stored in S), ``m_bytes`` (raw file over pathmap file), ``common_share`` (the
fraction of segment instances that are common; paper: 50.54 % for n_s = 3),
``max_error_mm`` (the largest distance between an original point and its
rebuilt counterpart; at most w_tip).
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
from surgiplan.plugins.planners.optmis.repository import Repository
from surgiplan.storage import atomic_write, write_bytes_atomic, write_text_atomic

from .pathmap import build_pathmap, raw_arrays, reconstruction_error

#: paper 001 Table 1 (KB) and §6: 1.46 MB of paths, m = 3.45 for n_s = 3
PAPER_TABLE1 = {2: (113, 153, 266), 3: (147, 272, 419), 4: (167, 373, 540), 5: (167, 447, 614)}
PAPER_RAW_KB = 1460
PAPER_M = 3.45

COLUMNS = [
    "method",
    "n_s",
    "paths",
    "segment_instances",
    "stored_segments",
    "common_segments",
    "unique_segments",
    "common_share",
    "common_kb",
    "unique_kb",
    "links_kb",
    "pathmap_kb",
    "raw_kb",
    "m",
    "m_bytes",
    "max_error_mm",
    "paper_common_kb",
    "paper_unique_kb",
    "paper_pathmap_kb",
]

METHODS = {
    "paper": {"alignment": "path", "reverse": False},
}


def _npz(arrays: dict) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def table1(
    repository: Repository,
    space,
    *,
    sizes=(2, 3, 4, 5),
    alignment: str = "corners",
    reverse: bool = True,
    tolerance: float | None = None,
    margin: float = 0.0,
    directory: Path | None = None,
    thinning: float = 0.0,
) -> list[dict]:
    """Table 1 rows for the paper's method and the configured one; writes the compared files to ``directory``."""
    raw = _npz(raw_arrays(repository))
    if directory is not None:
        write_bytes_atomic(Path(directory) / "repository.npz", raw)
    methods = {"paper": (METHODS["paper"]["alignment"], METHODS["paper"]["reverse"], 0.0)}
    ours = f"{alignment}{'+reverse' if reverse else ''}"
    if (alignment, reverse, 0.0) != methods["paper"]:
        methods[ours] = (alignment, reverse, 0.0)
    if thinning > 0:  # the configured encoding, beside the same segmentation without thinning
        methods[f"{ours}+thinned"] = (alignment, reverse, float(thinning))
    rows = []
    for method, (method_alignment, method_reverse, method_thinning) in methods.items():
        for n_s in sizes:
            pathmap = build_pathmap(
                repository,
                space,
                n_s=n_s,
                tolerance=tolerance,
                alignment=method_alignment,
                reverse=method_reverse,
                margin=margin,
                thinning=method_thinning,
            )
            data = _npz(pathmap.to_arrays())
            if directory is not None:
                write_bytes_atomic(Path(directory) / f"pathmap_{method}_ns{n_s}.npz", data)
            s = pathmap.stats
            paper = PAPER_TABLE1.get(n_s, (None, None, None))
            error = reconstruction_error(repository, pathmap)
            rows.append(
                {
                    "method": method,
                    "n_s": n_s,
                    "paths": s["paths"],
                    "segment_instances": s["segment_instances"],
                    "stored_segments": s["stored_segments"],
                    "common_segments": s["common_segments"],
                    "unique_segments": s["unique_segments"],
                    "common_share": round(s["common_instance_share"], 4),
                    "common_kb": round(s["common_bytes"] / 1e3, 1),
                    "unique_kb": round(s["unique_bytes"] / 1e3, 1),
                    "links_kb": round(s["links_bytes"] / 1e3, 1),
                    "pathmap_kb": round(len(data) / 1e3, 1),
                    "raw_kb": round(len(raw) / 1e3, 1),
                    "m": round(s["m"], 3),
                    "m_bytes": round(len(raw) / len(data), 3),
                    "max_error_mm": round(float(error.max()) * 1e3 if len(error) else 0.0, 4),
                    "paper_common_kb": paper[0],
                    "paper_unique_kb": paper[1],
                    "paper_pathmap_kb": paper[2],
                }
            )
    return rows


def write_csv(path: Path, rows: list[dict]) -> None:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=COLUMNS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if row.get(k) is None else row.get(k)) for k in COLUMNS})
    write_text_atomic(path, buffer.getvalue())


def bar_chart(path: Path, rows: list[dict], title: str = "") -> None:
    """Grouped bars per n_s: common, unique and pathmap KB for each method and the paper; m on top."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = list(dict.fromkeys(r["method"] for r in rows))
    sizes = sorted({r["n_s"] for r in rows})
    series = [(m, rows) for m in methods] + [("paper 001", None)]
    width = 0.8 / len(series)
    colours = {"common": "#1f6fb4", "unique": "#ff7f0e"}
    fig, (ax, ax_m) = plt.subplots(1, 2, figsize=(13, 5), gridspec_kw={"width_ratios": [3, 1.2]})
    x = np.arange(len(sizes))
    for k, (method, _) in enumerate(series):
        common, unique, links, m = [], [], [], []
        for n_s in sizes:
            if method == "paper 001":
                paper = PAPER_TABLE1.get(n_s, (0, 0, 0))
                common.append(paper[0])
                unique.append(paper[1])
                links.append(0.0)
                m.append(PAPER_M if n_s == 3 else np.nan)
            else:
                row = next(r for r in rows if r["method"] == method and r["n_s"] == n_s)
                common.append(row["common_kb"])
                unique.append(row["unique_kb"])
                links.append(max(row["pathmap_kb"] - row["common_kb"] - row["unique_kb"], 0.0))
                m.append(row["m"])
        offset = x - 0.4 + width * (k + 0.5)
        hatch = "//" if method == "paper 001" else None
        ax.bar(
            offset,
            common,
            width,
            color=colours["common"],
            hatch=hatch,
            edgecolor="white",
            label="common segments" if k == 0 else None,
        )
        ax.bar(
            offset,
            unique,
            width,
            bottom=common,
            color=colours["unique"],
            hatch=hatch,
            edgecolor="white",
            label="unique segments" if k == 0 else None,
        )
        ax.bar(
            offset,
            links,
            width,
            bottom=np.add(common, unique),
            color="#999999",
            hatch=hatch,
            edgecolor="white",
            label="references and delimiters" if k == 0 else None,
        )
        for xo, top in zip(offset, np.add(np.add(common, unique), links), strict=True):
            short = "thinned" if method.endswith("+thinned") else method.split("+")[0]
            ax.text(xo, top, short, ha="center", va="bottom", fontsize=6, rotation=90)
        ax_m.plot(sizes, m, "o-" if method != "paper 001" else "s", label=method)
    raw = next((r["raw_kb"] for r in rows), None)
    if raw:
        ax.axhline(raw, color="black", linestyle="--", linewidth=1, label=f"raw repository ({raw:.0f} KB)")
    ax.axhline(PAPER_RAW_KB, color="black", linestyle=":", linewidth=1, label=f"paper's raw paths ({PAPER_RAW_KB} KB)")
    ax.set_xticks(x, [f"n_s = {n}" for n in sizes])
    ax.set_ylabel("storage (KB)")
    ax.set_title("segmented pathmap size (hatched: paper 001 Table 1)")
    # below the axes, not over the n_s = 2 bars; headroom above the tallest bar for its label
    tallest = max([raw or 0.0, PAPER_RAW_KB] + [r["pathmap_kb"] for r in rows])
    ax.set_ylim(0, 1.12 * tallest)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3, frameon=False)
    ax_m.set_xlabel("segment size n_s")
    ax_m.set_ylabel("memory savings factor m = length(P) / |S|")
    ax_m.set_xticks(sizes)
    ax_m.grid(alpha=0.3)
    ax_m.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2, frameon=False)
    ax_m.set_title("m (paper eq. 1)")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_write(path, "wb") as handle:
        fig.savefig(handle, format="png", dpi=120)
    plt.close(fig)


def write_report(directory: Path, rows: list[dict], title: str = "") -> list[Path]:
    """``table1.csv`` and ``table1.png`` in ``directory``; returns their paths."""
    directory = Path(directory)
    csv_path, png_path = directory / "table1.csv", directory / "table1.png"
    write_csv(csv_path, rows)
    bar_chart(png_path, rows, title)
    return [csv_path, png_path]
