"""The MAVLink page's numbers are the benchmark's output, quoted as written (they cannot drift).

``python benchmarks/bench_mavlink.py`` flies the shipped configs/hall_flight.yaml and the other
sections and writes ``benchmarks/results/mavlink.md``; the MAVLink how-to page (docs/howto/mavlink.md) must
contain each of its tables verbatim (rerun the benchmark, then copy them, when the code changes what
they measure).
"""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def blocks(text: str) -> list[str]:
    """The tables of a markdown text: runs of lines that start with '|'."""
    out, current = [], []
    for line in text.splitlines():
        if line.startswith("|"):
            current.append(line.rstrip())
        elif current:
            out.append("\n".join(current))
            current = []
    if current:
        out.append("\n".join(current))
    return out


def test_readme_quotes_the_benchmark_tables_verbatim():
    section = (ROOT / "docs" / "howto" / "mavlink.md").read_text()
    results = (ROOT / "benchmarks" / "results" / "mavlink.md").read_text()
    tables = blocks(results)
    assert len(tables) >= 4, "the benchmark writes the hall, upload, tracking and speed/lockstep tables"
    quoted = blocks(section)
    for table in tables:
        assert table in quoted, f"docs/howto/mavlink.md does not quote this table as written:\n{table}"
    load = next(line for line in results.splitlines() if line.startswith("Load average"))
    assert load in section
