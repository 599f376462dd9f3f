"""Validating files against pydantic models, with every error named by file, YAML path and line.

:func:`validate_model` is ``model.model_validate(data)`` that raises :class:`~surgiplan.errors.ConfigErrors`
whose messages say where (``configs/x.yaml:8: pipeline[0].settings.milestone``) and, for an unknown key,
which keys are valid. Models read two keys of pydantic's validation context that the loaders set:
:data:`~surgiplan.units.LENGTH_SCALE_KEY` (metres per file unit) and :data:`BASE_DIR_KEY` (the directory
relative file names resolve against; plugin settings that name files read it through :func:`base_dir`).
"""

from __future__ import annotations

import typing
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError, ValidationInfo

from .errors import ConfigError, ConfigErrors, choices_hint
from .units import LENGTH_SCALE_KEY, LENGTH_UNITS
from .yamlio import LineMap, format_path, line_of

#: validation-context key holding the directory relative input files resolve against
BASE_DIR_KEY = "base_dir"
#: validation-context key holding the trainee record's path (settings may read a trainee's proficiency from it)
RECORD_KEY = "record"


def validation_context(unit: str, base_dir: Path) -> dict[str, Any]:
    """The validation context of a file written in ``unit`` whose relative paths resolve against ``base_dir``."""
    return {LENGTH_SCALE_KEY: LENGTH_UNITS[unit], BASE_DIR_KEY: base_dir}


def base_dir(info: ValidationInfo | None) -> Path:
    """In a pydantic validator: the directory the file being validated names other files relative to
    (the current directory when settings are built in Python)."""
    return Path(((info.context if info is not None else None) or {}).get(BASE_DIR_KEY, "."))


def input_path(name: str | Path, info: ValidationInfo | None) -> Path:
    """In a pydantic validator: the file a setting names, as an absolute path; a relative name resolves
    against the directory of the file being validated (``~`` expands), as every input file of surgiplan
    does. Existence is the caller's to check (and to report as a ``ValueError`` naming the path)."""
    path = Path(name).expanduser()
    return (path if path.is_absolute() else base_dir(info) / path).resolve()


def file_length_scale(info: ValidationInfo | None) -> float:
    """In a pydantic validator: metres per length unit of the file being validated (its ``length_unit``;
    1 when settings are built in Python). Values typed :data:`~surgiplan.units.Length` are already
    converted; this is for numbers a setting reads from a file of its own."""
    return float(((info.context if info is not None else None) or {}).get(LENGTH_SCALE_KEY, 1.0))


def declared_unit(data: Any, default: str, file: Path, lines: LineMap, prefix: tuple[Any, ...]) -> str:
    """The ``length_unit`` a mapping declares (``default`` if none); an unknown one is a
    :class:`~surgiplan.errors.ConfigError`."""
    unit = data.get("length_unit", default) if isinstance(data, dict) else default
    if unit is None:
        return default
    if unit not in LENGTH_UNITS:
        path = (*prefix, "length_unit")
        raise ConfigError(
            f"unknown length unit '{unit}'; choose one of: {', '.join(LENGTH_UNITS)}",
            file=file,
            location=format_path(path),
            line=line_of(lines, path),
        )
    return unit


def sorted_errors(errors: list[ConfigError]) -> list[ConfigError]:
    """By file, then line (errors without a line keep their place at the end of their file)."""
    order = {}
    for e in errors:
        order.setdefault(str(e.file), len(order))
    return sorted(errors, key=lambda e: (order[str(e.file)], e.line if e.line is not None else 10**9))


def _clean_loc(loc: tuple[Any, ...], data: Any, error_type: str) -> tuple[Any, ...]:
    """Drop pydantic's union tags and validator names: keep only keys present in the data."""
    out: list[Any] = []
    current = data
    for i, part in enumerate(loc):
        if isinstance(current, dict) and part in current:
            out.append(part)
            current = current[part]
        elif isinstance(current, list | tuple) and isinstance(part, int) and 0 <= part < len(current):
            out.append(part)
            current = current[part]
        elif i == len(loc) - 1 and error_type == "missing":
            out.append(part)
    return tuple(out)


def _unwrap_models(annotation: Any) -> list[type[BaseModel]]:
    found: list[type[BaseModel]] = []
    stack = [annotation]
    while stack:
        item = stack.pop()
        if isinstance(item, type) and issubclass(item, BaseModel):
            found.append(item)
        else:
            stack.extend(typing.get_args(item))
    return found


def _model_at(root: type[BaseModel], loc: tuple[Any, ...]) -> type[BaseModel] | None:
    model: type[BaseModel] | None = root
    for part in loc:
        if model is None:
            return None
        if isinstance(part, int):
            continue
        info = model.model_fields.get(part)
        if info is None:
            return None
        candidates = _unwrap_models(info.annotation)
        model = candidates[0] if len(candidates) == 1 else None
    return model


def validation_errors(
    exc: ValidationError,
    data: Any,
    *,
    file: Path | None,
    lines: LineMap,
    prefix: tuple[Any, ...] = (),
    root: type[BaseModel] | None = None,
) -> list[ConfigError]:
    """pydantic's errors as :class:`~surgiplan.errors.ConfigError` records with YAML paths and lines."""
    errors: list[ConfigError] = []
    for err in exc.errors(include_url=False):
        loc = _clean_loc(tuple(err["loc"]), data, err["type"])
        message = err["msg"].removeprefix("Value error, ").removeprefix("Assertion failed, ")
        if err["type"] == "extra_forbidden":
            key = str(loc[-1]) if loc else "?"
            parent = _model_at(root, loc[:-1]) if root is not None else None
            valid = sorted(parent.model_fields) if parent is not None else []
            message = f"unknown key '{key}'"
            if valid:
                message += f"; {choices_hint(key, valid)}"
        elif err["type"] == "missing":
            message = "required key is missing"
        full = (*prefix, *loc)
        errors.append(ConfigError(message, file=file, location=format_path(full), line=line_of(lines, full)))
    return errors


def validate_model(
    model: type[BaseModel],
    data: Any,
    *,
    file: Path | None = None,
    lines: LineMap | None = None,
    prefix: tuple[Any, ...] = (),
    context: dict[str, Any] | None = None,
) -> BaseModel:
    """``model.model_validate(data)``, raising :class:`~surgiplan.errors.ConfigErrors` that name file, path and line."""
    try:
        return model.model_validate(data, context=context or {})
    except ValidationError as exc:
        raise ConfigErrors(
            validation_errors(exc, data, file=file, lines=lines or {}, prefix=prefix, root=model)
        ) from None
