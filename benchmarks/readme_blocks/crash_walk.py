"""The crash walk's block (``benchmarks/crash_walk.py``): crash points per run kind and what was found."""

from __future__ import annotations

from pathlib import Path

from .formatting import load, table

LABELS = {
    "plan": "plan stage, stored artifact",
    "optmis": "optMIS repository build",
    "retraction": "FEM generation for retraction",
    "guide": "guide stage, trainee record",
}


def render_crash_walk(results: Path) -> str:
    data = load(results, "crash_walk")
    rows = []
    for r in data["rows"]:
        by = r["points_by_kind"]
        points = ", ".join(
            f"{by[k]} {k}" for k in ("write", "fsync", "rename", "sql", "commit", "committed") if k in by
        )
        states = r["states"]
        found = ", ".join(f"{states[k]} {k}" for k in ("old", "new", "complete", "partial") if states.get(k))
        rows.append(
            [
                LABELS.get(r["kind"], r["kind"]),
                f"{r['points']} ({points})",
                str(r["exercised"].get("kill", 0)),
                str(r["exercised"].get("fail", 0)),
                found,
                str(r["redone"]),
                str(len(r["problems"])),
            ]
        )
    total = sum(r["exercised"].get("kill", 0) + r["exercised"].get("fail", 0) for r in data["rows"])
    problems = sum(len(r["problems"]) for r in data["rows"])
    strides = {r["kind"]: r.get("stride", 1) for r in data["rows"]}
    full = [LABELS.get(k, k) for k, n in strides.items() if n == 1]
    partial = [f"{LABELS.get(k, k)} at every {_ordinal(n)}" for k, n in strides.items() if n != 1]
    every = "; ".join(
        ([f"{', '.join(full)} at every point"] if full else [])
        + ([", ".join(partial) + " (and always each kind of point's first and last)"] if partial else [])
    )
    verdict = (
        "no file was ever found partial or missing, no record failed its integrity check or lost a committed "
        "attempt, and no rerun redid committed work"
        if problems == 0
        else f"**{problems} problems** (listed in `benchmarks/results/crash_walk.json`)"
    )
    head = (
        f"`benchmarks/crash_walk.py` crashed the {every}: {total} crashes in all, a kill at each chosen point "
        f"and an I/O error at every third; after each it checked every file and the record, and (after a kill) a "
        f"rerun: {verdict}."
    )
    body = table(
        [
            "run kind",
            "crash points (by kind)",
            "kills",
            "I/O errors",
            "files after the crashes",
            "work redone",
            "problems",
        ],
        rows,
    )
    return head + "\n\n" + body


def _ordinal(n: int) -> str:
    return f"{n}{'th' if 10 <= n % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(n % 10, 'th')} point"
