"""The retraction blocks: Tables I and II of paper 002, and the speed-up of sample generation.

Both from ``bench_retraction.py`` (the speed-up from its ``--compare`` run).
"""

from __future__ import annotations

from pathlib import Path

from .formatting import find, load, section, sig, table


def render_retraction(results: Path) -> str:
    data = load(results, "retraction")
    table1 = {r["scenario"]: r for r in data["rows"] if r["table"] == "I"}
    table2 = {r["scenario"]: r for r in data["rows"] if r["table"] == "II"}
    names = {"max_energy": "min-max energy", "max_stress": "min-max stress"}
    rows = []
    for sc in sorted(table1):
        a, b = table1[sc], table2[sc]
        rows.append(
            [
                f"{sc} ({names.get(a['metric'], a['metric'])})",
                f"{a['samples']:,}",
                f"{a['generation_s']:.0f} s",
                f"{a['collision_s']:.2f} / {a['mesh_validation_s']:.2f} / {sig(a['fem_s'], 2)} / "
                f"{sig(a['planning_s'], 2)} s",
                f"{b['guided_samples']:,}, {b['guided_generation_s']:.0f} s; energy "
                f"{100 * b['rms_rel_error_max_energy']:.0f} %, stress {100 * b['rms_rel_error_max_stress']:.0f} %",
            ]
        )
    paper = [table1[sc] for sc in sorted(table1)]
    rows.append(
        [
            f"paper {' / '.join(str(sc) for sc in sorted(table1))} ({paper[0]['paper_cores']} cores)",
            f"{paper[0]['samples']:,}",
            " / ".join(f"{p['paper_generation_s'] / 3600:.1f} h" for p in paper),
            "; ".join(
                f"{sig(p['paper_collision_s'], 2)} / {sig(p['paper_mesh_validation_s'], 3)} / "
                f"{p['paper_fem_s']:.1f} / {p['paper_planning_s']:.0f} s"
                for p in paper
            ),
            f"{table2[min(table2)]['guided_samples']}; not published",
        ]
    )
    body = table(
        [
            "scenario",
            "samples",
            "generation",
            "planning: collision / mesh validation / FEM (worker s) / total",
            "user-guided: samples, generation, metric error vs random",
        ],
        rows,
    )
    load_avg = find(r"load average at the start ([\d.]+)", data["notes"], "retraction.json notes").group(1)
    workers = find(r"(\d+) workers", data["notes"], "retraction.json notes").group(1)
    head = (
        f"`benchmarks/bench_retraction.py` measures Tables I and II (`benchmarks/results/retraction.json`): both "
        f"scenarios at the paper's size, one grasp each, {workers} workers, on the machine shared with other work "
        f"(load average {load_avg} on its 2 cores at the start)."
    )
    planning_ok = [sc for sc, r in table1.items() if r["planning_s"] <= r["planning_target_s"]]
    target = paper[0]["planning_target_s"]
    verdict = (
        f"in both scenarios ({' and '.join(sig(r['planning_s'], 2) + ' s' for r in paper)})"
        if len(planning_ok) == len(table1)
        else f"in scenario(s) {', '.join(map(str, planning_ok)) or 'none'}"
    )
    worst = max(table2.values(), key=lambda r: r["rms_rel_error_max_stress"])
    tail = (
        f"Planning meets its target ({target} s) {verdict}. User-guided sampling around one straight line is a "
        f"poor substitute for random sampling in scenario {worst['scenario']}: the low-stress routes lie away from "
        f"the surgeon's line (+{100 * worst['rms_rel_error_max_stress']:.0f} % on the optimised stress)."
    )
    return section(head, body, tail)


def render_retraction_speed(results: Path) -> str:
    data = load(results, "retraction_speed")
    summary = {s["scenario"]: s for s in data["summary"]}
    rows, loads, costs = [], [], []
    for sc in sorted(summary):
        s = summary[sc]
        mine = [r for r in data["rows"] if r["scenario"] == sc]
        before = next(r for r in mine if r["tree"] == "baseline")
        now = next(r for r in mine if r["tree"] == "current")
        lo = min(x for r in mine for x in (r["load_start"], r["load_end"]))
        hi = max(x for r in mine for x in (r["load_start"], r["load_end"]))
        loads += [lo, hi]
        rows.append(
            [
                str(sc),
                f"{lo:.1f}-{hi:.1f}",
                f"{s['baseline_generation_s']:.1f} s",
                f"{s['current_generation_s']:.1f} s",
                f"{s['speedup']:.2f} ×",
                f"{before['fem_cpu_s']:.0f} → {now['fem_cpu_s']:.0f}",
                f"{s['valid_baseline_current'][0]} → {s['valid_baseline_current'][1]}",
                f"{s['goals_baseline_current'][0]} → {s['goals_baseline_current'][1]}",
            ]
        )
        costs += [abs(s["cost_change_max_energy"]), abs(s["cost_change_max_stress"])]
    body = table(
        ["scenario", "load", "before", "now", "speed-up", "worker FEM time (core s)", "valid states", "goal states"],
        rows,
    )
    base = find(r"baseline (\w+) =", data["notes"], "retraction_speed.json notes").group(1)
    head = (
        f"Speed-up of sample generation (`bench_retraction.py --compare {base}`): the code before the speed work "
        f"and this one, in the same run, each in a fresh process with an empty task store (1,000 random samples, "
        f"one grasp, 2 workers), the machine's 2 cores shared with other work (load average {min(loads):.1f} to "
        f"{max(loads):.1f} during the runs, `benchmarks/results/retraction_speed.json`):"
    )
    entries = [(sc, summary[sc]["current_generation_s"], summary[sc]["target_s"]) for sc in sorted(summary)]
    target = entries[0][2]
    times = " and ".join(f"{e[1]:.0f} s" for e in entries)
    ok = [e for e in entries if e[1] <= target]
    if len(ok) == len(entries):
        verdict = f"Both scenarios generate 1,000 samples within the issue's {target} s ({times})."
    elif not ok:
        verdict = f"Neither scenario generates 1,000 samples within the issue's {target} s ({times})."
    else:
        verdict = f"Only scenario {', '.join(str(e[0]) for e in ok)} is within the issue's {target} s ({times})."
    same = all(
        s["valid_baseline_current"][0] == s["valid_baseline_current"][1]
        and s["goals_baseline_current"][0] == s["goals_baseline_current"][1]
        for s in summary.values()
    )
    tail = (
        f"The plans are the same: both metrics' optimised costs within {max(costs):.0e} (relative) of the old "
        f"code's"
        + (
            ", from the same valid and goal states. "
            if same
            else (
                ". The sampled states are not all alike (the table's last columns): samples are solved as "
                "warm-started chains, and where the new line search takes a solve to convergence where the old one "
                "failed (or the reverse), or to another of the flap's equilibria, the local optimisation of the "
                "gripper's rotation and the rest of that chain follow it to other poses; the optimal plans do not "
                "change. "
            )
        )
        + verdict
    )
    return section(head, body, tail)
