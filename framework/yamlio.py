"""Safe YAML loading that remembers where every value came from, and refuses hostile documents.

Only plain data is constructed (``yaml.SafeLoader``: no Python objects).
Alongside the data, :func:`load_yaml` returns a map from YAML paths
(``("pipeline", 0, "settings", "milestones")``) to 1-based line numbers, so
validation errors can point at the line.

A file is data a user may have got from anyone, so:

* **aliases are bounded**: the document is composed once (anchors and
  aliases stay shared nodes, linear in the text), its size *as expanded* is
  counted on that graph before anything walks it as a tree, and a document
  that would expand to more than :data:`MAX_VALUES` values (a "billion
  laughs" alias bomb) or refers to itself is refused, in milliseconds and
  without the memory the expansion would take;
* **duplicate keys are an error** naming both lines (YAML 1.1 parsers keep
  the last one silently);
* **numbers are read as YAML 1.2 reads them**: ``1.4e2``, ``1e-3`` and
  ``.5`` are floats (YAML 1.1 makes the first two strings).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from .errors import ConfigError, SurgiplanError

LineMap = dict[tuple[Any, ...], int]

#: the most values (scalars, sequences and mappings, counted with every alias expanded) a file may hold
MAX_VALUES = 1_000_000

_FLOAT_1_2 = re.compile(
    r"""^(?:[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+
    |[-+]?\.[0-9][0-9_]*(?:[eE][-+]?[0-9]+)?)$""",
    re.X,
)


class SafeLoader(yaml.SafeLoader):
    """PyYAML's safe loader with YAML 1.2 floats (``1e-3``, ``1.4e2``) resolved as numbers."""

    yaml_implicit_resolvers = {k: list(v) for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()}  # noqa: RUF012


for _first in "-+0123456789.":
    SafeLoader.yaml_implicit_resolvers.setdefault(_first, []).insert(0, ("tag:yaml.org,2002:float", _FLOAT_1_2))

if getattr(yaml, "__with_libyaml__", False):

    class FastLoader(yaml.CSafeLoader):
        """The same loader on libyaml's parser (PyYAML's C extension): a scene of 10,000 obstacles (220,000
        values) composes in a second instead of twenty. A file it refuses is parsed again by :class:`SafeLoader`,
        so that messages do not depend on which parser is installed."""

        yaml_implicit_resolvers = SafeLoader.yaml_implicit_resolvers

else:  # pragma: no cover - PyYAML built without libyaml
    FastLoader = SafeLoader  # type: ignore[misc,assignment]


def load_yaml(path: str | Path) -> tuple[Any, LineMap]:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError("file not found", file=path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read file: {exc}", file=path) from None
    return parse_yaml(text, path)


def parse_yaml(text: str, path: str | Path = "<string>") -> tuple[Any, LineMap]:
    if FastLoader is not SafeLoader:
        if "&" not in text and "<<" not in text and "!" not in text:  # a plain tree: built from libyaml's events
            try:
                return _parse_events(text, path)
            except (_NotPlain, ConfigError, yaml.YAMLError, RecursionError):
                pass  # the composing parsers below answer it, and say what is wrong as they always have
        try:
            return _parse(text, path, FastLoader)
        except ConfigError:
            pass  # the pure-Python parser below says what is wrong, as it always has
    return _parse(text, path, SafeLoader)


class _NotPlain(SurgiplanError):
    """A document :func:`_parse_events` leaves to the composing parsers (several documents, complex keys)."""


_PLAIN_INT = re.compile(r"[-+]?(?:0|[1-9][0-9]*)")
_PLAIN_FLOAT = re.compile(r"[-+]?[0-9]+\.[0-9]*")


def _parse_events(text: str, path: str | Path) -> tuple[Any, LineMap]:
    """:func:`_parse` with :class:`FastLoader` for a document without anchors, aliases, tags or merge keys,
    built straight from libyaml's events: the same data, lines and refusals without composing a node graph
    first (a scene of 10,000 obstacles: 0.7 s of CPU instead of 2.7 s on a loaded machine). Each distinct
    scalar is resolved and constructed once, by the loader's own resolver and constructors (plain decimal
    integers and floats, the bulk of a large scene, directly: their value is the same)."""
    loader = FastLoader(text)
    cache: dict[tuple[str, bool], Any] = {}
    lines: LineMap = {}
    count = 0
    # one frame per open collection: [container, its path, the pending key (raw, constructed, line) or None,
    # the first line of each key]
    stack: list[list[Any]] = []
    root: Any = None
    events = yaml.events
    scalar_event, end_events = events.ScalarEvent, (events.MappingEndEvent, events.SequenceEndEvent)
    get_event, missing = loader.get_event, object()
    try:
        event = get_event()  # the stream's start
        event = get_event()
        if isinstance(event, events.StreamEndEvent):
            return None, lines
        if not isinstance(event, events.DocumentStartEvent):
            raise _NotPlain("not a document")
        while True:
            event = get_event()
            kind = type(event)
            if kind in end_events:
                stack.pop()
                continue
            if kind is events.DocumentEndEvent:
                break
            line = event.start_mark.line + 1
            frame = stack[-1] if stack else None
            if frame is not None and frame[2] is None and type(frame[0]) is dict:  # a mapping's key
                if kind is not scalar_event:
                    raise _NotPlain("a complex key")
                key = event.value
                _first_time(frame[3], key, line, path)
                made = cache.get((key, event.implicit[0]), missing)
                frame[2] = (key, _scalar(loader, event, cache) if made is missing else made, line)
                continue
            if frame is None:
                at: tuple[Any, ...] = ()
            elif frame[2] is None:
                at = (*frame[1], len(frame[0]))
            else:
                at = (*frame[1], frame[2][0])
                line_at = frame[2][2]
            count += 1
            if count > MAX_VALUES:
                raise ConfigError(f"the document holds more than {MAX_VALUES:,} values; refusing it", file=path)
            if kind is scalar_event:
                value = cache.get((event.value, event.implicit[0]), missing)
                if value is missing:
                    value = _scalar(loader, event, cache)
                opened = None
            elif kind is events.MappingStartEvent:
                value = opened = {}
            elif kind is events.SequenceStartEvent:
                value = opened = []
            else:
                raise _NotPlain("an alias")
            if frame is None:
                root = value
                lines[at] = line
            elif frame[2] is None:
                frame[0].append(value)
                lines[at] = line
            else:
                frame[0][frame[2][1]] = value
                lines[at] = line_at
                frame[2] = None
            if opened is not None:
                stack.append([opened, at, None, {}])
        if not isinstance(loader.get_event(), events.StreamEndEvent):
            raise _NotPlain("several documents")  # the composer refuses them with its own words
    finally:
        loader.dispose()
    return root, lines


def _scalar(loader, event, cache: dict[tuple[str, bool], Any]) -> Any:
    """A scalar event's value, as the composer and constructor of ``loader`` would make it."""
    plain = event.implicit[0]
    key = (event.value, plain)
    try:
        return cache[key]
    except KeyError:
        pass
    value = event.value
    if plain and _PLAIN_INT.fullmatch(value):
        made: Any = int(value)
    elif plain and _PLAIN_FLOAT.fullmatch(value):
        made = float(value)
    else:
        tag = loader.resolve(yaml.ScalarNode, value, event.implicit)
        node = yaml.ScalarNode(tag, value, event.start_mark, event.end_mark, event.style)
        made = loader.yaml_constructors[tag](loader, node)
    cache[key] = made
    return made


def _parse(text: str, path: str | Path, loader_type: type) -> tuple[Any, LineMap]:
    try:
        loader = loader_type(text)
        try:
            node = loader.get_single_node()
            lines: LineMap = {}
            if node is not None:
                if "&" in text:  # anchors, and so aliases, may be used: count the document as expanded first
                    _check_size(node, path)
                    _check_duplicate_keys(node, path)
                    _walk(node, (), lines)
                else:  # a tree: its size is its node count, and one walk finds duplicate keys and lines
                    _walk_tree(node, path, lines)
            data = loader.construct_document(node) if node is not None else None
        finally:
            loader.dispose()
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else None
        problem = " ".join(str(p) for p in (exc.context, exc.problem) if p)
        raise ConfigError(f"invalid YAML: {problem}", file=path, line=line) from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"invalid YAML: {exc}", file=path) from None
    except RecursionError:
        raise ConfigError("invalid YAML: nested too deeply", file=path) from None
    return data, lines


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


def _check_size(root: yaml.Node, path: str | Path) -> None:
    """Count the values of the document with every alias expanded, on the shared node graph (linear time).

    Refuses a node that contains itself and a document above :data:`MAX_VALUES`.
    """
    size: dict[int, int] = {}
    on_stack: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            on_stack.discard(key)
            total = 1 + sum(size[id(c)] for c in _children(node))
            if total > MAX_VALUES:
                raise ConfigError(
                    f"the document expands to more than {MAX_VALUES:,} values (counting every alias "
                    "*name as a copy of its &anchor); refusing it (nested aliases, a 'billion laughs' file?)",
                    file=path,
                    line=node.start_mark.line + 1,
                )
            size[key] = total
            continue
        if key in size:
            continue
        if key in on_stack:
            raise ConfigError("an alias refers to the value that contains it", file=path, line=node.start_mark.line + 1)
        on_stack.add(key)
        stack.append((node, True))
        for child in _children(node):
            if id(child) in on_stack:
                raise ConfigError(
                    "an alias refers to the value that contains it", file=path, line=child.start_mark.line + 1
                )
            if id(child) not in size:
                stack.append((child, False))


def _check_duplicate_keys(root: yaml.Node, path: str | Path) -> None:
    seen_nodes: set[int] = set()
    stack = [root]
    while stack:
        node = stack.pop()
        if id(node) in seen_nodes:
            continue
        seen_nodes.add(id(node))
        if isinstance(node, yaml.MappingNode):
            first: dict[Any, int] = {}
            for key_node, _ in node.value:
                if _key(key_node, path) == "<<":
                    continue
                _first_time(first, key_node.value, key_node.start_mark.line + 1, path)
        stack.extend(_children(node))


def _first_time(first: dict[Any, int], key: Any, line: int, path: str | Path) -> None:
    """Record that ``key`` of one mapping is on ``line``; a key seen before in it is refused (both lines)."""
    if key in first:
        raise ConfigError(
            f"duplicate key '{key}' (lines {first[key]} and {line}); a key may appear once per mapping",
            file=path,
            line=line,
        )
    first[key] = line


def _key(key_node: yaml.Node, path: str | Path) -> Any:
    """A mapping key's value: a scalar; a sequence or mapping as a key is refused (file and line)."""
    if not isinstance(key_node, yaml.ScalarNode):
        kind = "a list" if isinstance(key_node, yaml.SequenceNode) else "a mapping"
        raise ConfigError(
            f"invalid YAML: a key is {kind}; keys must be plain names or numbers",
            file=path,
            line=key_node.start_mark.line + 1,
        )
    return key_node.value


def _walk(node: yaml.Node, path: tuple[Any, ...], lines: LineMap) -> None:
    lines[path] = node.start_mark.line + 1
    if isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            key = key_node.value
            lines[(*path, key)] = key_node.start_mark.line + 1
            _walk(value_node, (*path, key), lines)
            lines[(*path, key)] = key_node.start_mark.line + 1
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _walk(item, (*path, i), lines)


def _walk_tree(root: yaml.Node, path: str | Path, lines: LineMap) -> None:
    """:func:`_walk`, :func:`_check_duplicate_keys` and :func:`_check_size` in one pass, for a document without
    anchors (every node reached once)."""
    count = 0
    stack: list[tuple[yaml.Node, tuple[Any, ...]]] = [(root, ())]
    while stack:
        node, at = stack.pop()
        count += 1
        lines.setdefault(at, node.start_mark.line + 1)
        if isinstance(node, yaml.MappingNode):
            first: dict[Any, int] = {}
            for key_node, value_node in node.value:
                key = _key(key_node, path)
                line = key_node.start_mark.line + 1
                if key != "<<":
                    _first_time(first, key, line, path)
                lines[(*at, key)] = line
                stack.append((value_node, (*at, key)))
        elif isinstance(node, yaml.SequenceNode):
            stack.extend((item, (*at, i)) for i, item in enumerate(node.value))
        if count > MAX_VALUES:
            raise ConfigError(f"the document holds more than {MAX_VALUES:,} values; refusing it", file=path)


def format_path(path: tuple[Any, ...]) -> str:
    """``("pipeline", 0, "settings", "k")`` -> ``pipeline[0].settings.k``."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else str(part)
    return out


def line_of(lines: LineMap, path: tuple[Any, ...]) -> int | None:
    """The line of the deepest known prefix of ``path``."""
    for end in range(len(path), -1, -1):
        if path[:end] in lines:
            return lines[path[:end]]
    return None
