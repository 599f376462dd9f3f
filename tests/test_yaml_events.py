"""The event-built YAML tree (``yamlio._parse_events``, libyaml's events without a node graph) against PyYAML's
own loader: the same values of the same types, the same line map as the composing path, and the composing
path's messages for every file it refuses."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml
from surgiplan import yamlio
from surgiplan.errors import ConfigError

pytestmark = pytest.mark.skipif(yamlio.FastLoader is yamlio.SafeLoader, reason="PyYAML built without libyaml")

ROOT = Path(__file__).resolve().parents[1]

DOCUMENTS = [
    "",
    "---\n",
    "# only a comment\n",
    "a: 1\nb: 'x'\nc: [1, 2.5, .5, 1e-3, 1.4e2, yes, No, ~, null, 0o1, 012, -0, +3, 1., 1_000, 0x1F, .inf, -.Inf,"
    " .nan, 1:30, 2001-12-14, 2001-12-14t21:59:43.10-05:00, '1', \"2\", '', -1.25, 007.5]\n",
    "- a\n- {b: c, d: [e, {f: g}]}\n- \n-\n  - 1\n  - [2, [3, [4]]]\n",
    "x: |\n  text\n  more\ny: >\n  folded\n  lines\nz: 'it''s'\n",
    "1: a\n2.5: b\nnull: c\ntrue: d\n'x': e\n",
    "a:\n  b:\n    c: 1\n  d: 2\ne: 3\nf:\n- 1\n- g: h\n  i: j\n",
    "plain",
    "3",
    "[1, 2]",
    "{}",
    "a: {}\nb: []\nc:\n",
]


def same(a, b) -> bool:
    """Equal values of identical types (``1``, ``1.0`` and ``True`` are different), keys included."""
    if type(a) is not type(b):
        return False
    if isinstance(a, dict):
        return [(type(k), k) for k in a] == [(type(k), k) for k in b] and all(same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and math.isnan(a):
        return math.isnan(b)
    return a == b


def shipped_documents() -> list[str]:
    """The shipped YAML files without anchors, tags or merge keys (those are left to the composing parsers)."""
    texts = [p.read_text() for d in ("configs", "examples") for p in sorted((ROOT / d).rglob("*.yaml"))]
    return [t for t in texts if not any(c in t for c in ("&", "!", "<<"))]


@pytest.mark.parametrize("text", DOCUMENTS + shipped_documents())
def test_event_tree_matches_pyyaml(text):
    data, lines = yamlio._parse_events(text, "x.yaml")
    assert same(data, yaml.load(text, Loader=yamlio.SafeLoader))  # PyYAML's pure-Python composer + constructor
    reference_data, reference_lines = yamlio._parse(text, "x.yaml", yamlio.SafeLoader)
    assert same(data, reference_data)
    assert lines == reference_lines


def test_large_generated_scene_matches_pyyaml():
    import sys

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from scale_scene import scene_text

    text = scene_text(300)
    data, lines = yamlio.parse_yaml(text, "scene.yaml")
    assert same(data, yaml.load(text, Loader=yamlio.SafeLoader))
    assert lines == yamlio._parse(text, "scene.yaml", yamlio.SafeLoader)[1]
    assert len(data["obstacles"]) == 300 and lines[("obstacles", 299, "pose", "xyz")] == 308


@pytest.mark.parametrize(
    ("text", "message", "line"),
    [
        ("a: 1\nb:\n  c: 2\n  c: 3\n", "duplicate key 'c' (lines 3 and 4)", 4),
        ("a: [1, 2\n", "invalid YAML", None),
        ("a: 1\n---\nb: 2\n", "invalid YAML", 2),
        ("1: a\n'1': b\n", "duplicate key '1' (lines 1 and 2)", 2),
    ],
)
def test_refused_documents_keep_the_composers_messages(text, message, line):
    with pytest.raises(ConfigError) as caught:
        yamlio.parse_yaml(text, "bad.yaml")
    with pytest.raises(ConfigError) as reference:
        yamlio._parse(text, "bad.yaml", yamlio.SafeLoader)
    assert str(caught.value) == str(reference.value)
    assert message in str(caught.value)
    if line is not None:
        assert caught.value.line == line
