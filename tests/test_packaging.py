"""The distribution a user installs: a wheel built from the tree, installed non-editable, runs the main job
and finds every data file; and building it prints no setuptools warning.

The wheel is built offline (``--no-build-isolation --no-index``, with the test environment's setuptools) and
installed with ``--target`` into a directory that comes first on ``PYTHONPATH``, so the run below imports the
installed copy, not the source tree (checked: ``surgiplan.__file__``).

The installed copy starts with the source tree's numba cache (``__pycache__/*.nbi``, ``*.nbc``, copied beside
the installed modules): numba keys each cached kernel by the SHA-256 of its module's bytes (numba >= 0.59), so
it loads a kernel only where the installed module is byte for byte the tree's, and compiles any other afresh.
The job then runs the wheel's code without compiling every kernel again (minutes on 2 loaded cores)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())

DATA_CHECK = """
import json, sys
from importlib import resources
import surgiplan
from surgiplan.plugins.devices.kinematics.model import urdf_path

found = {"surgiplan": surgiplan.__file__}
for package, patterns in DATA.items():
    root = resources.files(package)
    names = sorted(p.name for p in root.iterdir() if p.is_file() and not p.name.startswith("__"))
    found[package] = {name: len(root.joinpath(name).read_bytes()) for name in names}
found["urdf"] = [str(urdf_path("surgiplan.plugins.devices." + d, d)) for d in ("cast_gimbal", "gripper6")]
print(json.dumps(found))
"""


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """The wheel built from the tree, installed into its own directory: (that directory, the build's log)."""
    pytest.importorskip("wheel", reason="the dev extra installs wheel (offline wheel builds)")
    tmp = tmp_path_factory.mktemp("wheel")
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-w", tmp, ROOT],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp,
    )
    assert build.returncode == 0, build.stdout + build.stderr
    [wheel] = tmp.glob("surgiplan-*.whl")
    target = tmp / "site"
    install = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "--no-index", "--target", target, wheel],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert install.returncode == 0, install.stdout + install.stderr
    _copy_numba_cache(target)
    return target, build.stdout + build.stderr


def _copy_numba_cache(target: Path) -> int:
    """Copy the source tree's numba cache files beside their installed modules (numba itself checks that each
    installed module's bytes are the cached ones'); returns how many files were copied."""
    copied = 0
    for tree, installed in (
        (ROOT / "framework", target / "surgiplan"),
        (ROOT / "plugins", target / "surgiplan" / "plugins"),
    ):
        for cache in tree.rglob("__pycache__/*.nb[ic]"):
            package = installed / cache.parent.parent.relative_to(tree)
            if (package / "__init__.py").is_file():
                (package / "__pycache__").mkdir(exist_ok=True)
                shutil.copy2(cache, package / "__pycache__" / cache.name)
                copied += 1
    return copied


def _env(target: Path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(target), env.get("PYTHONPATH", "")])
    return env


def test_building_the_wheel_prints_no_setuptools_warning(installed):
    _, log = installed
    for warning in ("would be ignored", "is absent from the `packages` configuration", "SetuptoolsDeprecationWarning"):
        assert warning not in log, f"setuptools says {warning!r}:\n{log}"


def test_the_installed_wheel_has_every_data_file(installed):
    target, _ = installed
    data = {k: v for k, v in PYPROJECT["tool"]["setuptools"]["package-data"].items() if k != "surgiplan"}
    code = f"DATA = {data!r}\n" + DATA_CHECK
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=_env(target), cwd=target, timeout=120
    )
    assert result.returncode == 0, result.stderr
    found = json.loads(result.stdout)
    assert Path(found["surgiplan"]).is_relative_to(target)  # the installed copy, not the source tree
    for package in data:
        directory = (
            ROOT / "plugins" / Path(*package.split(".")[2:])
            if package.startswith("surgiplan.plugins.")
            else ROOT / "framework" / Path(*package.split(".")[1:])
        )
        expected = {p.name: p.stat().st_size for p in directory.iterdir() if p.is_file()}
        assert found[package] == expected, package
    assert all(Path(p).is_relative_to(target) and Path(p).is_file() for p in found["urdf"])


def test_the_installed_wheel_runs_the_main_job(installed, tmp_path):
    target, _ = installed
    main_job = ROOT / "configs" / "block_world_proficiency.yaml"
    result = subprocess.run(
        [sys.executable, "-m", "surgiplan.cli", "run", main_job, "--quiet", "--out", tmp_path / "out"],
        capture_output=True,
        text=True,
        env=_env(target),
        cwd=tmp_path,
        timeout=900,
    )
    assert result.returncode == 0, result.stderr
    document = json.loads((tmp_path / "out" / "result.json").read_text())
    assert document["status"] == "succeeded" and len(document["stages"]) == 4
    assert {"report.html", "overview.png", "scene.glb"} <= set(document["files"])
    html = (tmp_path / "out" / "report.html").read_text()
    assert "three" in html and len(html) > 500_000  # the page inlines the vendored viewer from the installed data
