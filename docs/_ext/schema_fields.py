"""The keys of a pydantic settings model as rows of a table: key, type, default, unit, description.

Descriptions come from ``Field(description=...)``, from the ``#:`` comments above a field (the project's
convention, which Sphinx's autodoc reads too) and from a comment at the end of the field's line
(``cruise_speed: PositiveFloat = 1.0  # m/s``). Types are read from the annotations, so a length
(:data:`surgiplan.units.Length` and its kin) shows as a length in the file's ``length_unit``.
"""

from __future__ import annotations

import inspect
import io
import re
import textwrap
import tokenize
import types
import typing
from dataclasses import dataclass

import annotated_types
from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined
from surgiplan import units

_FIELD_LINE = re.compile(r"^(\w+)\s*:")


@dataclass(frozen=True)
class Row:
    """One key of a settings block, flattened: ``smoothing.alpha``."""

    key: str
    type: str
    default: str
    unit: str
    description: str


def field_comments(model: type[BaseModel]) -> dict[str, str]:
    """Each field's ``#:`` comment (above it) and end-of-line comment, through the model's bases."""
    comments: dict[str, str] = {}
    for cls in reversed(model.__mro__):
        if not (isinstance(cls, type) and issubclass(cls, BaseModel)) or cls is BaseModel:
            continue
        try:
            source = textwrap.dedent(inspect.getsource(cls))
        except (OSError, TypeError):
            continue
        comments.update(_comments_in(source))
    return comments


def _comments_in(source: str) -> dict[str, str]:
    lines = source.splitlines()
    trailing: dict[int, str] = {}
    try:
        for tok in tokenize.generate_tokens(io.StringIO(source).readline):
            if tok.type == tokenize.COMMENT and not tok.string.startswith("#:"):
                if lines[tok.start[0] - 1][: tok.start[1]].strip():
                    trailing[tok.start[0]] = tok.string.lstrip("#").strip()
    except (tokenize.TokenError, IndentationError):
        pass
    found: dict[str, str] = {}
    above: list[str] = []
    for number, line in enumerate(lines[1:], start=2):
        body = line[4:] if line.startswith("    ") and not line.startswith("     ") else None
        stripped = line.strip()
        if stripped.startswith("#:"):
            above.append(stripped[2:].strip())
            continue
        match = _FIELD_LINE.match(body) if body is not None else None
        if match and not body.startswith(("def ", "class ", "model_config")):
            text = " ".join([*above, trailing.get(number, "")]).strip()
            if text:
                found[match.group(1)] = text
        above = []
    return found


def _validator_funcs(metadata) -> set:
    return {getattr(m, "func", None) for m in metadata}


def _bounds(metadata) -> str:
    parts = []
    for m in metadata:
        for attr, sign in (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤")):
            value = getattr(m, attr, None)
            if isinstance(m, annotated_types.BaseMetadata) and value is not None:
                parts.append(f"{sign} {value:g}" if isinstance(value, int | float) else f"{sign} {value}")
        if isinstance(m, annotated_types.MinLen) and m.min_length:
            parts.append(f"at least {m.min_length} long")
    return ", ".join(parts)


def type_text(annotation, metadata=()) -> tuple[str, str]:
    """(type, unit) of an annotation: ``("length ≥ 0", "length_unit")``, ``("float > 0", "")``."""
    funcs = _validator_funcs(metadata)
    if units._to_metres in funcs:
        sign = "> 0" if units._positive in funcs else "≥ 0" if units._non_negative in funcs else ""
        return f"length {sign}".strip(), "length_unit"
    if units._to_radians in funcs:
        return "angle", "rad"
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is typing.Annotated:
        return type_text(args[0], (*metadata, *annotation.__metadata__))
    bounds = _bounds(metadata)
    if origin is typing.Literal:
        return " | ".join(repr(a) if isinstance(a, str) else str(a) for a in args), ""
    if origin in (typing.Union, types.UnionType):
        parts = [type_text(a) for a in args]
        unit = next((u for _, u in parts if u), "")
        return " | ".join("none" if a is type(None) else t for a, (t, _) in zip(args, parts, strict=True)), unit
    if origin is tuple:
        parts = [type_text(a) for a in args if a is not Ellipsis]
        unit = next((u for _, u in parts if u), "")
        if Ellipsis in args:
            return f"[{parts[0][0]}, ...]", unit
        return "[" + ", ".join(t for t, _ in parts) + "]", unit
    if origin in (list, set, frozenset):
        inner, unit = type_text(args[0]) if args else ("any", "")
        return f"list of {inner}", unit
    if origin is dict:
        inner, unit = type_text(args[1]) if len(args) == 2 else ("any", "")
        return f"mapping of name to {inner}", unit
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "mapping", ""
    name = {int: "integer", float: "number", str: "text", bool: "true | false", type(None): "none"}.get(
        annotation, getattr(annotation, "__name__", str(annotation))
    )
    if name == "Any":
        name = "any"
    return f"{name} {bounds}".strip(), ""


def _default_text(field: FieldInfo, unit: str) -> str:
    if field.is_required():
        return "required"
    if field.default_factory is not None:
        value = field.default_factory()
        if isinstance(value, BaseModel):
            return "(the defaults below)"
    else:
        value = field.default
    if value is None:
        return "none"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, BaseModel):
        return "(the defaults below)"
    if unit == "length_unit":
        return f"{_plain(value)} m"
    if unit == "rad" and isinstance(value, float):
        return f"{value:.6g} rad"
    return _plain(value)


def _plain(value) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, tuple | list):
        return "[" + ", ".join(_plain(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_plain(v)}" for k, v in value.items()) + "}"
    if value is PydanticUndefined:
        return "required"
    return str(value)


def _models_in(annotation) -> list[tuple[str, type[BaseModel]]]:
    """The models a field holds, with the key suffix that reaches them: '' (itself), '.<name>', '[]'."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [("", annotation)]
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Annotated:
        return _models_in(args[0])
    if origin in (typing.Union, types.UnionType):
        return [m for a in args for m in _models_in(a)]
    if origin is list:
        return [("[]" + s, m) for s, m in _models_in(args[0])] if args else []
    if origin is dict and len(args) == 2:
        return [(".<name>" + s, m) for s, m in _models_in(args[1])]
    return []


def rows(model: type[BaseModel], prefix: str = "", seen: frozenset = frozenset()) -> list[Row]:
    """Every key of ``model``, nested models flattened (``smoothing.alpha``), in declaration order."""
    comments = field_comments(model)
    out: list[Row] = []
    for name, field in model.model_fields.items():
        key = prefix + (field.alias or name)
        kind, unit = type_text(field.annotation, field.metadata)
        nested = [(s, m) for s, m in _models_in(field.annotation) if m not in seen]
        description = " ".join(p for p in (field.description or "", comments.get(name, "")) if p)
        out.append(Row(key, kind, _default_text(field, unit), unit, description))
        for suffix, sub in nested:
            sub_rows = rows(sub, f"{key}{suffix}.", seen | {model, sub})
            if len(nested) > 1:  # one of several forms: say which each key belongs to
                form = f"(the {sub.__name__} form)"
                sub_rows = [Row(r.key, r.type, r.default, r.unit, f"{form} {r.description}".strip()) for r in sub_rows]
            out.extend(sub_rows)
    return out


def model_summary(model: type[BaseModel]) -> str:
    """The first paragraph of the model's own docstring (not pydantic's)."""
    doc = model.__dict__.get("__doc__") or ""
    return inspect.cleandoc(doc).split("\n\n")[0].replace("\n", " ") if doc else ""
