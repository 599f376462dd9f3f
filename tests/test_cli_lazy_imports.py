"""A quick command line: ``import surgiplan`` and building the CLI parser load no scientific library.

Each check runs in a fresh interpreter (this test process has imported everything long ago) and reads
``sys.modules`` there: it asserts which modules are loaded, not how long it took (issue #38, item 4;
the times are measured in benchmarks/bench_cli.py).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import surgiplan

#: libraries a stage loads when it needs them, never ``import surgiplan`` or ``surgiplan --help``
HEAVY = ("numba", "pinocchio", "coal", "matplotlib", "trimesh", "scipy", "numpy", "pydantic", "dask", "canopen")


def _loaded_after(code: str) -> set[str]:
    probe = f"{code}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, check=True)
    return set(json.loads(done.stdout.strip().splitlines()[-1]))


def _heavy(modules: set[str]) -> list[str]:
    return sorted({m.split(".")[0] for m in modules} & set(HEAVY))


def test_import_surgiplan_loads_no_heavy_library():
    loaded = _loaded_after("import surgiplan")
    assert _heavy(loaded) == []
    # and none of the core's own modules but the package and its lazy-name helper
    assert sorted(m for m in loaded if m.startswith("surgiplan.")) == ["surgiplan.lazy"]


def test_cli_parser_and_help_load_no_heavy_library():
    loaded = _loaded_after(
        "import contextlib, io\n"
        "from surgiplan.cli import _parser, main\n"
        "_parser()\n"
        "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
        "    main(['--help'])\n"
        "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
        "    main(['run', '--help'])\n"
    )
    assert _heavy(loaded) == []
    assert "surgiplan.runner" not in loaded and "surgiplan.pipeline" not in loaded


def test_the_lazy_names_are_the_public_names_and_each_resolves():
    # the table __getattr__ reads and __all__ name the same things, and each name is its module's object
    assert sorted(surgiplan._LAZY) == sorted(surgiplan.__all__)
    for name, module in surgiplan._LAZY.items():
        value = getattr(surgiplan, name)
        assert value is getattr(sys.modules[f"surgiplan{module}"], name), name
    assert set(surgiplan.__all__) <= set(dir(surgiplan))
    assert surgiplan.__version__ == __import__("importlib.metadata").metadata.version("surgiplan")
    with pytest.raises(AttributeError, match="no attribute 'NoSuchName'"):
        surgiplan.NoSuchName  # noqa: B018


def test_version_option_reads_the_installed_version():
    done = subprocess.run(
        [sys.executable, "-m", "surgiplan.cli", "--version"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0
    assert done.stdout.strip() == f"surgiplan {surgiplan.__version__}"
