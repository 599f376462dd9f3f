"""Plugin discovery through entry points: the example package, conflicts, disabling, broken plugins."""

from __future__ import annotations

import importlib
import inspect
import json
import textwrap

import pytest
from conftest import ROOT
from surgiplan import hookspecs, registry
from surgiplan.errors import PluginError
from surgiplan.registry import PluginRegistry

GOOD_PLUGIN = textwrap.dedent("""\
    from pydantic import BaseModel, ConfigDict
    from surgiplan import Planner, PluginSpec, hookimpl

    class Settings(BaseModel):
        model_config = ConfigDict(extra="forbid")

    class Copycat(Planner):
        Settings = Settings
        def build(self, problem): return None
        def query(self, artifact, start, goal): raise NotImplementedError

    @hookimpl
    def surgiplan_register_planners():
        return [PluginSpec("{name}", Copycat, "a test plugin")]
    """)


def fake_distribution(root, dist, module, code, monkeypatch, entry_point=None):
    """A real installed distribution as importlib.metadata sees one: a module plus a .dist-info."""
    (root / f"{module}.py").write_text(code)
    info = root / f"{dist.replace('-', '_')}-2.5.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 2.5\n")
    (info / "entry_points.txt").write_text(f"[surgiplan]\n{entry_point or module} = {module}\n")
    monkeypatch.syspath_prepend(str(root))
    importlib.invalidate_caches()
    packages = set(filter(None, __import__("os").environ.get("SURGIPLAN_PLUGIN_PACKAGES", "").split(",")))
    monkeypatch.setenv("SURGIPLAN_PLUGIN_PACKAGES", ",".join(packages | {dist}))


def test_example_third_party_package_is_discovered(with_example_plugin, cli):
    info = with_example_plugin.get("planner", "via_point")
    assert (info.package, info.version, info.entry_point) == ("surgiplan-hello", "1.0.0", "hello")
    code, out, _ = cli("plugins", "--json")
    rows = {(r["name"], r["kind"]): r for r in json.loads(out)["plugins"]}
    assert rows[("via_point", "planner")]["package"] == "surgiplan-hello"
    assert rows[("r3", "space")]["package"] == "surgiplan"
    assert code == 0


def test_builtins_register_through_our_own_entry_points():
    from importlib.metadata import entry_points

    ours = {ep.name for ep in entry_points(group="surgiplan") if ep.dist.name == "surgiplan"}
    assert {"spaces", "ompl_bridge"} <= ours
    registry = PluginRegistry(packages={"surgiplan"})
    assert {"r3", "cast_gimbal", "se3"} <= set(registry.names("space"))


def test_example_plugin_plans_a_real_path(with_example_plugin, cli, tmp_path):
    config = tmp_path / "hello.yaml"
    config.write_text(
        textwrap.dedent(f"""\
        name: hello
        length_unit: mm
        scene: {ROOT}/configs/scenes/block_world.yaml
        pipeline:
          - {{stage: plan, plugin: via_point, settings: {{via_points: 400, seed: 3}},
             start: [60, 30, 20], goal: [95, 30, 20]}}
        output: {{dir: {tmp_path}/out}}
        """)
    )
    code, _, err = cli("run", config, "--quiet")
    assert code == 0, err
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    stage = result["stages"][0]
    assert stage["status"] == "solved" and stage["plugin"] == "via_point"
    assert stage["metrics"]["legs"] == 2  # the straight line crosses block B1
    assert stage["metrics"]["min_clearance_m"] > 0


def test_two_plugins_with_one_name_refuse_the_second_naming_both(tmp_path, monkeypatch, cli):
    """A clash refuses one plugin, not the command line: the first registration keeps the name, the rest of the
    second package keeps working, and `surgiplan plugins` (the command to diagnose it) shows the refusal."""
    code = GOOD_PLUGIN.replace("{name}", "ompl") + (
        "\n@hookimpl\ndef surgiplan_register_spaces():\n"
        "    from surgiplan import R3Space\n    return [PluginSpec('copied_space', R3Space, 'another space')]\n"
    )
    fake_distribution(tmp_path, "copycat-planners", "copycat_a", code, monkeypatch)
    registry = PluginRegistry()
    assert registry.get("planner", "ompl").package == "surgiplan"
    assert registry.get("space", "copied_space").package == "copycat-planners"  # the rest of the package loads
    [failure] = registry.failures
    assert (failure.package, failure.entry_point) == ("copycat-planners", "copycat_a")
    assert "planner 'ompl' from package 'copycat-planners' (entry point 'copycat_a') is refused" in failure.error
    assert "package 'surgiplan' (entry point 'ompl_bridge') registered it first" in failure.error
    code, out, err = cli("plugins", "--json")
    assert code == 0 and "Traceback" not in err
    listing = json.loads(out)
    assert listing["failures"][0]["error"] == failure.error
    code, out, _ = cli("plugins")
    assert code == 0 and "failed:" in out and "copycat-planners" in out
    # strict mode (for plugin authors) refuses the whole load, naming both
    with pytest.raises(PluginError, match=r"'copycat-planners'.*'surgiplan'"):
        PluginRegistry(strict=True)
    # the way out the message suggests works
    registry = PluginRegistry(disabled={"copycat_a"})
    assert registry.get("planner", "ompl").package == "surgiplan" and not registry.failures


def test_disable_by_entry_point_or_plugin_name(tmp_path, monkeypatch):
    fake_distribution(tmp_path, "extra-planners", "extra_b", GOOD_PLUGIN.replace("{name}", "copycat"), monkeypatch)
    assert "copycat" in PluginRegistry().names("planner")
    monkeypatch.setenv("SURGIPLAN_DISABLE_PLUGINS", "extra_b")  # the entry point
    assert "copycat" not in PluginRegistry().names("planner")
    monkeypatch.setenv("SURGIPLAN_DISABLE_PLUGINS", "copycat")  # the plugin
    registry = PluginRegistry()
    assert "copycat" not in registry.names("planner")
    with pytest.raises(PluginError, match="disabled by SURGIPLAN_DISABLE_PLUGINS"):
        registry.get("planner", "copycat")


def test_plugin_that_raises_on_import_is_logged_and_skipped(tmp_path, monkeypatch, caplog, cli):
    fake_distribution(
        tmp_path, "broken-planners", "broken_c", "raise RuntimeError('missing licence file')\n", monkeypatch
    )
    with caplog.at_level("WARNING"):
        registry = PluginRegistry()
    assert "broken_c" in caplog.text and "broken-planners" in caplog.text and "missing licence file" in caplog.text
    assert registry.names("space")  # everything else still works
    with pytest.raises(PluginError, match="failed to load: 'broken_c' \\(broken-planners\\)"):
        registry.get("planner", "broken")
    # strict mode (for plugin authors): the command fails, naming the plugin, exit 2
    monkeypatch.setenv("SURGIPLAN_STRICT_PLUGINS", "1")
    code, _, err = cli("plugins")
    assert code == 2 and "broken_c" in err and "missing licence file" in err and "Traceback" not in err


def test_misspelt_hook_name_is_reported(tmp_path, monkeypatch, caplog):
    code = GOOD_PLUGIN.replace("{name}", "typo")
    code = code.replace("def surgiplan_register_planners", "def surgiplan_register_planner")
    fake_distribution(tmp_path, "typo-planners", "typo_d", code, monkeypatch)
    with caplog.at_level("WARNING"):
        PluginRegistry()
    assert "typo_d" in caplog.text and "surgiplan_register_planner" in caplog.text
    with pytest.raises(PluginError, match="typo_d"):
        PluginRegistry(strict=True)


def test_plugin_without_settings_model_is_rejected(tmp_path, monkeypatch, caplog):
    code = GOOD_PLUGIN.replace("{name}", "nosettings").replace("    Settings = Settings\n", "")
    fake_distribution(tmp_path, "nosettings-planners", "nosettings_e", code, monkeypatch)
    with caplog.at_level("WARNING"):
        registry = PluginRegistry()
    assert "Copycat has no pydantic Settings model" in caplog.text
    assert "nosettings" not in registry.names("planner")


def test_a_class_that_is_not_a_planner_is_refused_naming_the_package(tmp_path, monkeypatch, caplog):
    code = GOOD_PLUGIN.replace("{name}", "notaplanner").replace("class Copycat(Planner):", "class Copycat:")
    fake_distribution(tmp_path, "notaplanner-planners", "notaplanner_e", code, monkeypatch)
    with caplog.at_level("WARNING"):
        registry = PluginRegistry()
    assert (
        "planner 'notaplanner' from package 'notaplanner-planners' (entry point 'notaplanner_e') is refused: "
        "Copycat is not a subclass of surgiplan.Planner" in caplog.text
    )
    assert "notaplanner" not in registry.names("planner")
    with pytest.raises(PluginError, match="notaplanner-planners"):
        PluginRegistry(strict=True)


@pytest.mark.parametrize("where", ["top", "nested"])
def test_settings_that_accept_unknown_keys_are_refused(tmp_path, monkeypatch, caplog, where):
    """A Settings model without extra="forbid" (at any level) would let a typo pass silently."""
    code = GOOD_PLUGIN.replace("{name}", "lenient")
    if where == "top":
        code = code.replace('model_config = ConfigDict(extra="forbid")', "pass")
        expected = "its settings model Settings accepts unknown keys"
    else:
        code = code.replace(
            "class Settings(BaseModel):",
            "class Inner(BaseModel):\n    x: int = 0\n\n\nclass Settings(BaseModel):\n    inner: Inner = Inner()",
        )
        expected = "its settings model Settings.inner accepts unknown keys"
    fake_distribution(tmp_path, f"lenient-{where}-planners", f"lenient_{where}", code, monkeypatch)
    with caplog.at_level("WARNING"):
        registry = PluginRegistry()
    assert expected in caplog.text and f"'lenient-{where}-planners'" in caplog.text
    assert "lenient" not in registry.names("planner")


def test_missing_optional_dependency_says_how_to_install(monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ompl" else real(name, *a))
    registry = PluginRegistry()
    with pytest.raises(PluginError, match=r"pip install 'surgiplan\[ompl\]'"):
        registry.get("planner", "ompl")


def test_every_hook_is_documented_and_tested():
    """Like datasette's: a hook without a docstring, a mention in the plugin guide or a test fails here."""
    readme = (ROOT / "docs" / "howto" / "write-a-plugin.md").read_text()
    tests = "".join(p.read_text() for p in (ROOT / "tests").glob("test_*.py"))
    specs = {name: f for name, f in inspect.getmembers(hookspecs, inspect.isfunction) if name.startswith("surgiplan_")}
    for info in registry.default_registry().stage_kinds.values():  # each stage kind declares its plugins' hook
        specs.update(
            (name, f)
            for name, f in inspect.getmembers(info.kind.hookspecs, inspect.isfunction)
            if name.startswith("surgiplan_")
        )
    hooks = sorted(specs)
    assert len(hooks) == 6
    for name in hooks:
        assert (specs[name].__doc__ or "").strip(), f"{name} has no docstring"
        assert name in readme, f"{name} is not documented in docs/howto/write-a-plugin.md"
        assert name in tests.replace(f"hookspecs, {name}", ""), f"{name} has no test"


@pytest.mark.parametrize(
    "hook",
    [
        "surgiplan_register_deformable_models",
        "surgiplan_register_devices",
        "surgiplan_register_spaces",
        "surgiplan_register_sources",
    ],
)
def test_other_plugin_kinds_register_the_same_way(tmp_path, monkeypatch, hook):
    base = {
        "surgiplan_register_deformable_models": (
            "DeformableModel",
            "    rest_nodes = elements = None\n"
            "    def solve(self, constraints, initial=None): raise NotImplementedError\n",
        ),
        "surgiplan_register_devices": ("Device", "    def run(self, trajectory): raise NotImplementedError\n"),
        "surgiplan_register_spaces": ("R3Space", ""),
        "surgiplan_register_sources": ("PoseSource", "    def samples(self): return iter(())\n"),
    }[hook]
    code = GOOD_PLUGIN.replace("{name}", "kindprobe").replace("surgiplan_register_planners", hook)
    code = code.replace("from surgiplan import Planner,", f"from surgiplan import {base[0]},")
    code = code.replace(
        "class Copycat(Planner):\n    Settings = Settings\n"
        "    def build(self, problem): return None\n"
        "    def query(self, artifact, start, goal): raise NotImplementedError\n",
        f"class Copycat({base[0]}):\n    Settings = Settings\n{base[1]}",
    )
    module = f"kind_{hook.split('_')[-1]}"
    fake_distribution(tmp_path, f"{module}-pkg".replace("_", "-"), module, code, monkeypatch)
    registry = PluginRegistry()
    kind = {
        "surgiplan_register_deformable_models": "deformable_model",
        "surgiplan_register_devices": "device",
        "surgiplan_register_spaces": "space",
        "surgiplan_register_sources": "source",
    }[hook]
    assert "kindprobe" in registry.names(kind)
