"""The documentation's measured numbers come from the benchmarks' result files, through benchmarks/readme_tables.py.

A number typed by hand drifts (issue 21: the hall flight's door clearances in the README were not what
the shipped config flies). Every benchmark figure README.md or a page under docs/ quotes sits in a generated
block, each block in exactly one page; these tests check that each block is what its results render to, that
a hand edit or a changed result is caught, that the sentences' judgements (a target met or not) follow the
data, and that a benchmark figure is not also quoted outside its block in its page.
"""

from __future__ import annotations

import json
import re
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import readme_tables as rt  # noqa: E402

PAGES = rt.pages(ROOT)


@pytest.fixture()
def results(tmp_path: Path) -> Path:
    copy = tmp_path / "results"
    shutil.copytree(rt.RESULTS, copy)
    return copy


def edit_json(path: Path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def flat(text: str) -> str:
    """The text with its line breaks undone (the renderers wrap paragraphs at 78 columns)."""
    return " ".join(text.split())


def block(text: str, name: str) -> str:
    start, end = rt.spans(text)[name]
    return text[start:end]


def page_of(name: str) -> Path:
    return rt.locate(ROOT)[name]


def test_every_generated_block_is_what_its_results_render_to():
    located = rt.locate(ROOT)
    assert set(located) == set(rt.BLOCKS), "each block appears in exactly one page"
    assert ROOT / "docs" / "howto" / "planners" / "safe-prm.md" == located["safe_prm"], "blocks live with their topic"
    for page, _, changed in rt.regenerate_all(ROOT):
        assert changed == [], f"run python benchmarks/readme_tables.py: stale blocks {changed} in {page}"


def test_every_results_file_a_page_cites_is_rendered_by_a_block():
    cited = set()
    for page in PAGES:
        cited |= set(re.findall(r"benchmarks/results/(\w+)\.json", page.read_text()))
    rendered = {source for b in rt.BLOCKS.values() for source in b.sources}
    assert cited, "the pages cite their results files"
    assert cited <= rendered, f"quoted but not generated: {sorted(cited - rendered)}"


def test_a_block_in_two_pages_or_in_none_is_named(tmp_path: Path, capsys):
    root = tmp_path / "repo"
    (root / "docs").mkdir(parents=True)
    guide = page_of("guide").read_text()
    (root / "README.md").write_text(guide)
    (root / "docs" / "a.md").write_text(guide)
    assert rt.main(["--check", "--root", str(root)]) == 2
    assert "docs/a.md: block 'guide' is also in README.md" in capsys.readouterr().err
    (root / "docs" / "a.md").write_text("no blocks here\n")
    assert rt.main(["--check", "--root", str(root)]) == 2
    assert "no generated block for " in capsys.readouterr().err


def test_a_hand_edited_number_is_caught_and_named():
    text = page_of("safe_prm").read_text()
    original = block(text, "safe_prm")
    row = next(line for line in original.splitlines() if line.startswith("| 5,000 |"))
    number = re.search(r"\d+\.\d+[x×]", row).group(0)
    edited = text.replace(original, original.replace(row, row.replace(number, "999.9×")))
    _, changed = rt.regenerate(edited)
    assert changed == ["safe_prm"]
    fixed, _ = rt.regenerate(edited)
    assert fixed == text, "rewriting restores the page exactly"


def test_a_changed_result_changes_the_table(results: Path):
    path = results / "mavlink.json"
    edit_json(
        path,
        lambda d: [r.update(door_min_clearance_m=0.123) for r in d["rows"] if r.get("flight") == "mission"],
    )
    mission = next(r for r in json.loads(path.read_text())["rows"] if r.get("flight") == "mission")
    tracking = f"{mission['tracking_error_max_m']:.3f} / {mission['tracking_error_rms_m']:.3f} m"
    assert f"| mission | {tracking} | 0.123 m |" in rt.render_mavlink_hall(results)


def safe_prm_at_5000(row: dict) -> bool:
    """safe_prm's row at 5,000 milestones: the table's run, and each run when the benchmark ran several (--runs)."""
    return row["milestones"] == 5000 and (
        row["planner"].startswith("safe_prm (") or row["planner"] == "safe_prm, every run"
    )


def test_the_sentences_judge_the_targets_from_the_data(results: Path):
    def faster(d):
        for r in d["rows"]:
            if safe_prm_at_5000(r):
                r["build_ratio_vs_strongest"] = "12.5x"
                r["query_repair_ms_4mm"], r["query_repair_ms_8mm"] = "0.083", "0.074"

    edit_json(results / "safe_prm_vs_ompl.json", faster)
    text = flat(rt.render_safe_prm(results))
    assert "milestones: met (12.5× against" in text
    assert "at 5,000 milestones: met (83 / 74 µs)" in text

    def slower(d):
        for r in d["rows"]:
            if safe_prm_at_5000(r):
                r["build_ratio_vs_strongest"] = "8.1x"
                r["query_repair_ms_8mm"] = "0.24"

    edit_json(results / "safe_prm_vs_ompl.json", slower)
    text = flat(rt.render_safe_prm(results))
    assert "milestones: not met (8.1× against" in text
    assert "at 5,000 milestones: not met (83 / 240 µs)" in text

    edit_json(
        results / "optmis.json",
        lambda d: [r.update(value=1.7) for r in d["rows"] if r["measure"].startswith("online query between free")],
    )
    assert "all 1,000 solved: not met (1.7 ms" in flat(rt.render_optmis(results))

    def generation(first: float, second: float):
        def change(d):
            d["summary"][0]["current_generation_s"], d["summary"][1]["current_generation_s"] = first, second
            d["summary"][0]["target_s"] = d["summary"][1]["target_s"] = 150

        return change

    edit_json(results / "retraction_speed.json", generation(128.0, 96.0))
    speed = flat(rt.render_retraction_speed(results))
    assert "both scenarios generate 1,000 samples within the issue's 150 s (128 s and 96 s)" in speed.lower()
    edit_json(results / "retraction_speed.json", generation(128.0, 171.0))
    speed = flat(rt.render_retraction_speed(results))
    assert "only scenario 1 is within the issue's 150 s (128 s and 171 s)" in speed.lower()
    assert "| 171.0 s |" in speed
    edit_json(results / "retraction_speed.json", generation(181.0, 171.0))
    assert "neither scenario generates 1,000 samples within" in flat(rt.render_retraction_speed(results)).lower()

    def same_states(d):
        for s in d["summary"]:
            s["valid_baseline_current"] = [s["valid_baseline_current"][0]] * 2
            s["goals_baseline_current"] = [s["goals_baseline_current"][0]] * 2

    edit_json(results / "retraction_speed.json", same_states)
    speed = flat(rt.render_retraction_speed(results))
    assert "from the same valid and goal states" in speed and "not all alike" not in speed

    def runs(*speedups):
        return lambda r: r.update(
            speedup=min(speedups), speedup_runs=list(speedups), holds_every_run=min(speedups) >= 2.0
        )

    edit_json(results / "fem_vs_fenicsx.json", lambda d: [runs(2.5, 2.6, 2.7)(r) for r in d["rows"]])
    fem = flat(rt.render_fem_vs_fenicsx(results))
    assert "holds on every case in every run (the smallest ratio 2.50" in fem and "not on" not in fem
    edit_json(results / "fem_vs_fenicsx.json", lambda d: runs(2.3, 1.9, 2.2)(d["rows"][1]))
    fem = flat(rt.render_fem_vs_fenicsx(results))
    assert "holds in every run on six of the seven cases and not on quadratic cantilever 20×2×2" in fem
    assert "(2.30 / 1.90 / 2.20)" in fem

    edit_json(results / "guide.json", lambda d: d["rows"][1].update(analysis_p99_ms=6.0))
    guide = rt.render_guide(results)
    assert guide.count("| met |") == 1 and guide.count("| not met |") == 1


@pytest.mark.parametrize(
    ("readme", "message"),
    [
        ("<!-- generated by benchmarks/readme_tables.py: report -->\nx\n", "block 'report' has no 'end generated"),
        ("<!-- end generated: report -->\n", "'end generated: report' without its beginning"),
        (
            "<!-- generated by benchmarks/readme_tables.py: nosuch -->\n<!-- end generated: nosuch -->\n",
            "unknown block 'nosuch'",
        ),
        (
            "<!-- generated by benchmarks/readme_tables.py: report -->\n<!-- end generated: report -->\n" * 2,
            "block 'report' appears twice",
        ),
        (
            "<!-- generated by benchmarks/readme_tables.py: report -->\n"
            "<!-- generated by benchmarks/readme_tables.py: guide -->\n",
            "block 'guide' begins inside block 'report' (line 2)",
        ),
        (
            "<!-- generated by benchmarks/readme_tables.py: report -->\n<!-- end generated: report -->\n",
            "no generated block for safe_prm",
        ),
    ],
)
def test_malformed_markers_are_named_with_their_line(tmp_path: Path, readme: str, message: str, capsys):
    path = tmp_path / "README.md"
    path.write_text("intro\n" + readme)
    assert rt.main(["--root", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert message in err and ("README.md" in err), err
    assert path.read_text() == "intro\n" + readme, "nothing written"


def test_safe_prm_targets_are_judged_on_the_worst_of_several_runs(results: Path):
    """bench_safe_prm.py --runs N records each run's figures; one run that misses a target makes it not met, however
    well the last run (the table's) did."""

    def runs(slow_first: bool):
        def change(d):
            d["rows"] = [r for r in d["rows"] if r["planner"] != "safe_prm, every run"]
            last = next(r for r in d["rows"] if safe_prm_at_5000(r))  # the table's row: the runs' rows are gone
            last.update(
                build_ratio_vs_strongest="14.5x",
                query_repair_warm_ms_4mm="0.087",
                query_repair_warm_ms_8mm="0.078",
                query_repair_ms_4mm="0.09",
                query_repair_ms_8mm="0.08",
            )
            first = dict(last, planner="safe_prm, every run", run=1, steal_ticks=9)
            if slow_first:
                first.update(build_ratio_vs_strongest="9.5x", query_repair_warm_ms_4mm="0.14")
            d["rows"] += [first, dict(last, planner="safe_prm, every run", run=2, steal_ticks=2)]

        return change

    edit_json(results / "safe_prm_vs_ompl.json", runs(True))
    text = flat(rt.render_safe_prm(results))
    assert "milestones: not met (14.5× against" in text  # the table's run met it; the first did not
    assert "Every run (2 in a row" in text and "build ratio 9.5× (" in text and ", 14.5× (" in text
    assert "warm query with repair 4 / 8 mm 140 / 78, 87 / 78 µs; ticks stolen 9, 2." in text
    assert "(the target measured this way: not met)" in text

    shutil.copy(rt.RESULTS / "safe_prm_vs_ompl.json", results / "safe_prm_vs_ompl.json")
    edit_json(results / "safe_prm_vs_ompl.json", runs(False))
    text = flat(rt.render_safe_prm(results))
    assert "milestones: met (14.5× against" in text
    assert "(the target measured this way: met)" in text


def copy_pages(root: Path) -> list[Path]:
    """README.md and the docs pages copied under ``root``, as the repository has them."""
    copies = []
    for page in PAGES:
        copy = root / page.relative_to(ROOT)
        copy.parent.mkdir(parents=True, exist_ok=True)
        copy.write_text(page.read_text())
        copies.append(copy)
    return copies


def test_check_and_rewrite_from_the_command_line(tmp_path: Path, results: Path, capsys):
    root = tmp_path / "repo"
    copy_pages(root)
    guide = root / page_of("guide").relative_to(ROOT)
    original = guide.read_text()
    assert rt.main(["--check", "--root", str(root), "--results", str(results)]) == 0

    edit_json(results / "guide.json", lambda d: d["rows"][0].update(analysis_median_ms=0.0777))
    assert rt.main(["--check", "--root", str(root), "--results", str(results)]) == 1
    assert "docs/howto/guidance.md: out of date with benchmarks/results: guide" in capsys.readouterr().err
    assert guide.read_text() == original, "--check writes nothing"

    assert rt.main(["--root", str(root), "--results", str(results)]) == 0
    assert "| 0.078 / " in block(guide.read_text(), "guide")
    assert rt.main(["--check", "--root", str(root), "--results", str(results)]) == 0

    (results / "optmis.json").unlink()
    before = {p: p.read_text() for p in root.rglob("*.md")}
    edit_json(results / "guide.json", lambda d: d["rows"][0].update(analysis_median_ms=0.0888))
    assert rt.main(["--root", str(root), "--results", str(results)]) == 2
    err = capsys.readouterr().err
    assert "optmis.json: missing" in err
    assert {p: p.read_text() for p in root.rglob("*.md")} == before, "a failed rendering writes no page at all"


#: figures that a block quotes and the prose uses for another meaning (a protocol timeout, a vehicle's
#: radius, a setting's value, the paper's figure), so their appearing outside the blocks is not a copy
COINCIDENCES = {"0.25 s", "0.1 mm", "67.6 s", "0.3 ms", "0.25 m", "0.5 m"}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_benchmark_figure_is_also_typed_outside_its_block(page: Path):
    text = page.read_text()
    found = rt.spans(text)
    outside = text
    for start, end in sorted(found.values(), reverse=True):
        outside = outside[:start] + outside[end:]
    figure = re.compile(r"(?<![\w.])\d[\d,]*\.\d+ ?(?:x|×|ms|s|%|µs|mm|m|h|MB|kPa)(?!\w)")
    copies = []
    for name, (start, end) in found.items():
        for token in set(figure.findall(text[start:end])) - COINCIDENCES:
            if re.search(rf"(?<![\w.]){re.escape(token)}(?!\w)", outside):
                copies.append(f"{name}: {token}")
    assert copies == [], f"benchmark figures typed outside their generated blocks: {copies}"
