"""Plugins named by ``"module:Class"``: imported and checked at first use, with the same refusals as a class given
directly; listing the plugins and validating a small pipeline load no plugin's heavy libraries (issue #38)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest
from conftest import ROOT
from surgiplan import registry
from surgiplan.errors import PluginError
from surgiplan.registry import PluginRegistry, plugin_class_problem
from test_plugins import GOOD_PLUGIN, fake_distribution

#: a plugin whose package names its class by where it is; the class's module says when it is imported
LAZY_PLUGIN = textwrap.dedent("""\
    from surgiplan import PluginSpec, hookimpl

    @hookimpl
    def surgiplan_register_planners():
        return [PluginSpec("{name}", "{module}_impl:Copycat", "a lazily named test plugin")]
    """)


def lazy_distribution(tmp_path, monkeypatch, name: str, impl: str) -> str:
    module = f"{name}_lazy"
    (tmp_path / f"{module}_impl.py").write_text(impl)
    code = LAZY_PLUGIN.replace("{name}", name).replace("{module}", module)
    fake_distribution(tmp_path, f"{name}-planners", module, code, monkeypatch)
    return f"{module}_impl"


def test_a_class_named_by_reference_is_imported_at_first_use(tmp_path, monkeypatch):
    impl = lazy_distribution(tmp_path, monkeypatch, "lazycat", GOOD_PLUGIN.replace("{name}", "unused"))
    sys.modules.pop(impl, None)
    reg = PluginRegistry()
    assert "lazycat" in reg.names("planner")
    assert impl not in sys.modules  # registered, listed, not imported
    info = reg.get("planner", "lazycat")
    assert impl in sys.modules
    assert info.cls is sys.modules[impl].Copycat and info.settings_model is sys.modules[impl].Settings
    assert info.target == f"{impl}:Copycat"


def test_a_referenced_class_that_is_not_a_planner_is_refused_when_used(tmp_path, monkeypatch):
    code = GOOD_PLUGIN.replace("{name}", "unused").replace("class Copycat(Planner):", "class Copycat:")
    lazy_distribution(tmp_path, monkeypatch, "lazybad", code)
    reg = PluginRegistry()
    with pytest.raises(PluginError) as caught:
        reg.get("planner", "lazybad", location="pipeline[0].plugin")
    message = str(caught.value)
    assert "planner 'lazybad' from package 'lazybad-planners'" in message
    assert "Copycat is not a subclass of surgiplan.Planner" in message
    assert caught.value.location == "pipeline[0].plugin"


@pytest.mark.parametrize(
    ("impl", "expected"),
    [
        ("raise ImportError('no such library: fancy_solver')", "ImportError: no such library: fancy_solver"),
        ("x = 1", "has no 'Copycat'"),
    ],
)
def test_a_referenced_class_that_does_not_import_names_the_plugin(tmp_path, monkeypatch, impl, expected):
    lazy_distribution(tmp_path, monkeypatch, "lazybroken", impl)
    reg = PluginRegistry()
    with pytest.raises(PluginError, match="planner 'lazybroken' from package 'lazybroken-planners'") as caught:
        reg.get("planner", "lazybroken")
    assert expected in str(caught.value)


def test_every_builtin_reference_resolves_to_a_valid_plugin_class():
    """What the registry checked at load when the classes were given directly, checked here for every built-in
    plugin named by reference."""
    reg = registry.default_registry()
    named = [info for info in reg.all() if isinstance(info.target, str)]
    assert {"safe_prm", "optmis", "retraction", "stvk", "cast_gimbal", "mavlink_vehicle"} <= {i.name for i in named}
    for info in named:
        if info.unavailable:
            continue
        assert plugin_class_problem(reg.plugin_kinds[info.kind], info.cls) == "", info.name
        assert info.cls.__name__ == info.target.rsplit(":", 1)[1]


def _loaded_by(args: list[str]) -> tuple[int, set[str]]:
    probe = (
        "import contextlib, io, json, sys\n"
        "from surgiplan.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        f"    code = main({args!r})\n"
        "print(json.dumps([code, sorted({m.split('.')[0] for m in sys.modules})]))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=300, check=True
    )
    code, loaded = json.loads(done.stdout.strip().splitlines()[-1])
    return code, set(loaded)


#: what neither listing the plugins nor validating a plan pipeline needs
NOT_NEEDED = {"matplotlib", "trimesh", "pinocchio", "osqp", "canopen", "can", "pymavlink", "meshio", "dask"}


def test_listing_the_plugins_loads_no_plugin_implementation():
    code, loaded = _loaded_by(["plugins", "--json"])
    assert code == 0
    assert sorted(loaded & (NOT_NEEDED | {"numba", "scipy"})) == []


def test_validating_a_small_plan_pipeline_loads_only_what_its_checks_use():
    code, loaded = _loaded_by(["validate", "configs/block_world_proficiency.yaml"])
    assert code == 0
    assert sorted(loaded & NOT_NEEDED) == []
