"""Executors give the same results; task sets resume without recomputing finished work."""

from __future__ import annotations

import numpy as np
import pytest
from surgiplan.executors import DaskExecutor, InlineExecutor, LocalExecutor, TaskStore, run_tasks


def chunks(scene, seed=7, n=6, size=400):
    rng = np.random.default_rng(seed)
    return [rng.uniform(scene.bounds_min, scene.bounds_max, (size, 3)) for _ in range(n)]


def clearance_task(args):
    scene, points = args
    distance, index = scene.signed_distance(points)
    return {"distance": distance, "index": index, "count": len(points)}


def test_local_process_pool_equals_inline(block_world):
    work = [(block_world, c) for c in chunks(block_world)]
    inline = InlineExecutor().map(clearance_task, work)
    with LocalExecutor(workers=2) as executor:
        pooled = executor.map(clearance_task, work)
    for a, b in zip(inline, pooled, strict=True):
        np.testing.assert_array_equal(a["distance"], b["distance"])
        np.testing.assert_array_equal(a["index"], b["index"])


@pytest.mark.dask
def test_dask_cluster_equals_local(block_world):
    distributed = pytest.importorskip("distributed")
    work = [(block_world, c) for c in chunks(block_world)]
    with LocalExecutor(workers=2) as executor:
        local = executor.map(clearance_task, work)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        with DaskExecutor(cluster.scheduler_address) as executor:
            remote = executor.map(clearance_task, work)
    for a, b in zip(local, remote, strict=True):
        np.testing.assert_array_equal(a["distance"], b["distance"])
        np.testing.assert_array_equal(a["index"], b["index"])


@pytest.mark.dask
def test_dask_workers_without_the_stages_packages_are_named_at_connect_time():
    distributed = pytest.importorskip("distributed")
    import numpy
    from surgiplan.errors import ExecutorError

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        required = {"surgiplan-missing-plugins": "1.0", "numpy": "0.0.1"}
        with pytest.raises(ExecutorError) as info:
            DaskExecutor(cluster.scheduler_address, required=required)
        message = str(info.value)
        workers = sorted(cluster.scheduler_info["workers"])
        assert len(workers) == 2
        for worker in workers:
            assert f"worker {worker} does not have surgiplan-missing-plugins installed (this run uses 1.0)" in message
            assert f"worker {worker} has numpy {numpy.__version__}, this run uses 0.0.1" in message
        with DaskExecutor(cluster.scheduler_address, required={"numpy": numpy.__version__}) as executor:
            assert executor.map(abs, [-1, -2]) == [1, 2]  # the same versions: accepted


def test_the_dask_version_probe_needs_no_surgiplan_on_the_worker():
    """The probe travels by value: a worker that cannot import surgiplan still runs it and is named."""
    import subprocess
    import sys

    cloudpickle = pytest.importorskip("cloudpickle")
    from surgiplan.executors import _version_probe

    payload = cloudpickle.dumps(_version_probe())
    code = (
        "import sys, pickle; sys.modules['surgiplan'] = None; "
        "f = pickle.loads(sys.stdin.buffer.read()); print(f(['surgiplan-missing-plugins', 'numpy']))"
    )
    out = subprocess.run([sys.executable, "-c", code], input=payload, capture_output=True, timeout=60)
    assert out.returncode == 0, out.stderr.decode()
    assert "'surgiplan-missing-plugins': None" in out.stdout.decode()


def test_unreachable_dask_scheduler_is_a_clear_error():
    pytest.importorskip("distributed")
    from surgiplan.errors import ExecutorError

    with pytest.raises(ExecutorError, match=r"cannot reach a dask scheduler at tcp://127\.0\.0\.1:1"):
        DaskExecutor("tcp://127.0.0.1:1", timeout=1.0)


class Interrupt(BaseException):
    """Stands for Ctrl-C in the middle of a task set."""


def test_interrupted_task_set_resumes_without_recomputing(tmp_path):
    calls: list[int] = []
    interrupt_at = {4}

    def task(seed):
        calls.append(seed)
        if seed in interrupt_at:
            raise Interrupt
        rng = np.random.default_rng(seed)
        return {"sample": rng.normal(size=5), "seed": seed}

    tasks = {f"pair-{i}": i for i in range(10)}
    store = TaskStore(tmp_path / "checkpoints")
    with pytest.raises(Interrupt):
        run_tasks(InlineExecutor(), task, tasks, store=store)
    finished = [k for k in tasks if k in store]
    assert finished == [f"pair-{i}" for i in range(4)]

    calls.clear()
    interrupt_at.clear()
    resumed = run_tasks(InlineExecutor(), task, tasks, store=store)
    assert calls == list(range(4, 10)), "finished tasks are loaded, not recomputed"
    clean = run_tasks(InlineExecutor(), task, tasks)
    for key in tasks:
        np.testing.assert_array_equal(resumed[key]["sample"], clean[key]["sample"])
        assert resumed[key]["seed"] == clean[key]["seed"]


def test_a_damaged_checkpoint_is_recomputed(tmp_path):
    store = TaskStore(tmp_path)
    run_tasks(InlineExecutor(), lambda s: {"value": np.array([s])}, {"a": 1, "b": 2}, store=store)
    path = next(p for p in tmp_path.iterdir() if p.name.startswith("a."))
    path.write_bytes(b"truncated")
    result = run_tasks(InlineExecutor(), lambda s: {"value": np.array([s * 10])}, {"a": 1, "b": 2}, store=store)
    assert result["a"]["value"].tolist() == [10] and result["b"]["value"].tolist() == [2]
