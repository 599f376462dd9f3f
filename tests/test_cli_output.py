"""What a user reads after a run: the summary table, -v, --quiet, progress bars named after their stage,
and the figures' legend, critical regions and height cue (issue 21)."""

from __future__ import annotations

import numpy as np
import yaml
from conftest import CONFIGS


def via_point_pipeline(tmp_path, stages=None, **output):
    data = {
        "name": "cli-probe",
        "length_unit": "mm",
        "scene": str(CONFIGS / "scenes" / "block_world.yaml"),
        "pipeline": stages
        or [
            {
                "stage": "plan",
                "name": "left",
                "plugin": "via_point",
                "settings": {"via_points": 100, "seed": 3},
                "start": "entry",
                "goal": "target",
                "clearance_threshold": 1,  # via_point keeps it on every motion
            },
        ],
        "output": {"dir": str(tmp_path / "out"), **output},
    }
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_quiet_prints_one_line_saying_where_the_results_are(cli, tmp_path, with_example_plugin):
    code, out, err = cli("run", via_point_pipeline(tmp_path, figures=False, gltf=False), "--quiet")
    assert code == 0, err
    assert out.strip() == f"cli-probe: 1 of 1 stages succeeded; results in {tmp_path / 'out' / 'result.json'}"
    assert err == ""


def test_verbose_logs_each_stage_artifacts_and_files(cli, tmp_path, with_example_plugin):
    stage = {
        "stage": "plan",
        "name": "left",
        "plugin": "via_point",
        "settings": {"via_points": 100},
        "start": "entry",
        "goal": "target",
        "artifact": str(tmp_path / "via.npz"),
    }
    path = via_point_pipeline(tmp_path, [stage], figures=False, gltf=False)
    code, _, err = cli("-v", "run", path, "--quiet")
    assert code == 0
    assert "info: pipeline 'cli-probe': 1 stages, executor local" in err
    assert f"info: no stored artifact at {tmp_path / 'via.npz'} yet; building" in err
    assert f"info: stored the via_point artifact in {tmp_path / 'via.npz'}" in err
    assert "info: plan stage 'left' (via_point): solved" in err
    assert "info: wrote in" in err and "result.json" in err
    code, _, err = cli("-v", "run", path, "--quiet")
    assert f"info: reusing the stored via_point artifact {tmp_path / 'via.npz'}" in err
    code, _, err = cli("run", path, "--quiet")  # without -v: nothing on stderr
    assert err == ""


def test_the_summary_shows_threshold_message_and_each_kinds_figures(tmp_path):
    from rich.console import Console
    from surgiplan.outputs.summary import summary_table
    from surgiplan.results import StageResult

    results = [
        StageResult(
            "plan",
            "beginner",
            "safe_prm",
            "solved",
            clearance_threshold=0.008,
            message="1 critical region(s) below the 8 mm threshold",
            metrics={
                "length_m": 0.1876,
                "min_clearance_m": 0.003,
                "length_below_threshold_m": 0.02546,
                "build_s": 0.2,
                "query_s": 0.05,
            },
        ),
        StageResult(
            "simulate",
            "flap",
            "stvk",
            "converged",
            metrics={"energy_J": 1.23e-3, "max_stress_Pa": 1.889e6, "max_displacement_m": 0.0152},
        ),
        StageResult(
            "execute",
            "gimbal",
            "cast_gimbal",
            "stopped",
            message="heartbeat lost on node 2",
            metrics={
                "tracking_error_max_m": 8.4e-5,
                "tracking_error_rms_m": 4.7e-5,
                "faults": [{"kind": "heartbeat_loss", "node": 2}],
            },
        ),
        StageResult("plan", "bad", "hostile", "invalid_result", message="segment 0 is not certified clear"),
    ]
    console = Console(width=250, record=True)
    console.print(summary_table("probe", results, unit="mm", unit_scale=1e-3, output_dir="out"))
    text = console.export_text()
    beginner = next(line for line in text.splitlines() if "beginner" in line)
    assert "187.6" in beginner and "│          3 │         8 │     25.46 │" in beginner
    assert "1 critical region(s) below the 8 mm threshold" in beginner
    assert "energy 1.23 mJ; max stress 1.89 MPa; max displacement 15.2 mm" in text
    assert "tracking max 0.084 mm, rms 0.047 mm; 1 fault (heartbeat_loss); heartbeat lost on node 2" in text
    assert "invalid_result" in text and "segment 0 is not certified clear" in text


def test_progress_bars_are_named_after_their_stage():
    from surgiplan.progress import Progress, StageProgress

    seen = []

    class Recorder(Progress):
        def task(self, description, total=None):
            seen.append(description)
            return super().task(description, total)

    inner = Recorder()
    with StageProgress(inner, "expert").task("sampling milestones", 10):
        pass
    with StageProgress(inner, "flap").task("flap: static equilibrium", 1):
        pass
    assert seen == ["expert: sampling milestones", "flap: static equilibrium"]


def test_a_finished_bar_ends_full_and_an_abandoned_one_where_it_got_to():
    import io

    from rich.console import Console
    from surgiplan.progress import RichProgress

    progress = RichProgress(Console(file=io.StringIO(), force_terminal=True, width=100))
    with progress.task("flying offboard", total=98.4) as task:
        task.update(97.9)  # the last position report came 0.5 mm before the goal: the flight arrived
    with progress.task("flying mission", total=7) as task:
        task.update(3)
        task.abandon()  # the vehicle left mission mode by itself
    try:
        with progress.task("uploading", total=5) as task:
            task.update(2)
            raise RuntimeError("link lost")
    except RuntimeError:
        pass
    progress.close()
    done = {t.description: t.completed for t in progress._progress.tasks}
    assert done == {"flying offboard": 98.4, "flying mission": 3, "uploading": 2}


def test_the_figures_have_a_legend_critical_regions_and_a_height_cue(tmp_path, block_world):
    """Drawn on a scene and a path built for it: the legend lists what is drawn, the critical region is
    circled, and the top view says where the path passes over a block and how high."""
    import matplotlib

    matplotlib.use("Agg")
    from surgiplan.outputs import figures

    tall = block_world.with_bounds([0, 0, 0], [0.150, 0.100, 0.080])
    # over A2 at 50 mm, down to 20 mm, back through the left gap (6 mm wide, 3 mm clearance) and on to the goal
    tips = np.array(
        [
            [0.010, 0.070, 0.050],
            [0.060, 0.070, 0.050],
            [0.060, 0.050, 0.020],
            [0.010, 0.050, 0.020],
            [0.140, 0.050, 0.020],
        ]
    )
    legs = [np.linspace(tips[i], tips[i + 1], 50, endpoint=False) for i in range(len(tips) - 1)]
    dense = np.concatenate([*legs, tips[-1:]])
    clearance = block_world.clearance(dense)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
    in_gap = np.flatnonzero((dense[:, 0] >= 0.035) & (dense[:, 0] <= 0.045) & (dense[:, 2] < 0.03))
    view = figures.PathView(
        "probe", dense, clearance, 0.004, tips[0], tips[-1], highlights=[(arc[in_gap[0]], arc[in_gap[-1]])]
    )
    over = figures._over_obstacles(tall, dense)
    assert [(name, round(z * 1000)) for _, _, name, z in over] == [("A2", 50)]
    fig = figures.plt.figure()
    figures._legend(fig, tall, [view], "mm", 1000.0)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    figures.plt.close(fig)
    assert labels == [
        "path",
        "start",
        "goal",
        "obstacle",
        "clearance below 4 mm",
        "critical region (no safe detour)",
        "passes over an obstacle",
    ]
    figures.plan_figure(tmp_path / "probe.png", tall, view, unit="mm", unit_scale=1e-3)
    assert (tmp_path / "probe.png").stat().st_size > 20_000
