"""Units: lengths and angles in files, SI inside.

A scene or pipeline file may declare ``length_unit: mm`` (or ``um``, ``cm``,
``m``; default ``m``). Plain numbers in fields typed :data:`Length`,
:data:`Coordinate` or :data:`Vec3` are then read in that unit and converted to
metres once, when the file is validated. A string with an explicit unit
(``"4 mm"``, ``"0.5 cm"``) is always read in its own unit. Angles
(:data:`Angle`) are radians unless written with a unit (``"30 deg"``).

Plugin authors type their settings with these aliases and get the conversion
for free (:data:`Length` refuses negatives and NaN; :data:`PositiveLength` also
zero; :data:`SignedLength`, alias :data:`Coordinate`, takes any finite value)::

    class Settings(StrictModel):
        clearance: Length = 0.004   # m

The conversion reads the scale from pydantic's validation context
(``{"length_scale": 0.001}``); without a context (settings built in Python),
numbers are SI.
"""

from __future__ import annotations

import math
import re
from typing import Annotated, Any

from pydantic import AfterValidator, BeforeValidator, ValidationInfo
from pydantic_core import PydanticCustomError

#: metres per unit
LENGTH_UNITS: dict[str, float] = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6}
#: radians per unit
ANGLE_UNITS: dict[str, float] = {"rad": 1.0, "deg": math.pi / 180.0}

_QUANTITY = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zA-Z]+)\s*$")

#: key of the validation context that holds metres per file unit
LENGTH_SCALE_KEY = "length_scale"


def length_scale(unit: str) -> float:
    """Metres per ``unit``; raises ``ValueError`` naming the valid units."""
    try:
        return LENGTH_UNITS[unit]
    except KeyError:
        raise ValueError(f"unknown length unit '{unit}'; choose one of: {', '.join(LENGTH_UNITS)}") from None


def _parse_with_unit(text: str, table: dict[str, float], what: str) -> float:
    match = _QUANTITY.match(text)
    if not match:
        raise PydanticCustomError(
            "quantity",
            "expected a number or a number with a unit (e.g. '4 {example}'), got '{text}'",
            {"text": text, "example": "mm" if what == "length" else "deg"},
        )
    number, unit = match.groups()
    if unit not in table:
        raise PydanticCustomError(
            "unit",
            "unknown {what} unit '{unit}'; choose one of: {choices}",
            {"what": what, "unit": unit, "choices": ", ".join(table)},
        )
    return float(number) * table[unit]


def _to_metres(value: Any, info: ValidationInfo) -> Any:
    if isinstance(value, bool):
        raise PydanticCustomError(
            "length_type", "expected a length (a number), got {value}", {"value": str(value).lower()}
        )
    if isinstance(value, int | float):
        scale = (info.context or {}).get(LENGTH_SCALE_KEY, 1.0)
        return float(value) * scale
    if isinstance(value, str):
        return _parse_with_unit(value, LENGTH_UNITS, "length")
    return value


def _to_radians(value: Any) -> Any:
    if isinstance(value, str):
        return _parse_with_unit(value, ANGLE_UNITS, "angle")
    return value


def _finite(value: float) -> float:
    if not math.isfinite(value):
        raise PydanticCustomError("finite", "must be a finite number, got {value}", {"value": value})
    return value


def _in_file_unit(value: float, info: ValidationInfo | None) -> str:
    """``value`` (m) written in the file's length unit: -0.003 in an mm file -> '-3 mm'."""
    scale = ((info.context if info is not None else None) or {}).get(LENGTH_SCALE_KEY, 1.0)
    unit = next((name for name, s in LENGTH_UNITS.items() if s == scale), "m")
    return f"{value / LENGTH_UNITS[unit]:.6g} {unit}"


def _non_negative(value: float, info: ValidationInfo) -> float:
    _finite(value)
    if value < 0:
        raise PydanticCustomError(
            "non_negative_length", "must be a non-negative length, got {value}", {"value": _in_file_unit(value, info)}
        )
    return value


def _positive(value: float, info: ValidationInfo) -> float:
    _finite(value)
    if value <= 0:
        raise PydanticCustomError(
            "positive_length", "must be a positive length, got {value}", {"value": _in_file_unit(value, info)}
        )
    return value


#: A non-negative length in metres (files: their ``length_unit``, or ``"4 mm"``).
Length = Annotated[float, BeforeValidator(_to_metres), AfterValidator(_non_negative)]
#: A strictly positive length in metres.
PositiveLength = Annotated[float, BeforeValidator(_to_metres), AfterValidator(_positive)]
#: A coordinate in metres (any sign).
Coordinate = Annotated[float, BeforeValidator(_to_metres), AfterValidator(_finite)]
#: A length that may be negative (an offset, a signed distance): the same as :data:`Coordinate`.
SignedLength = Coordinate
#: An angle in radians (files: radians, or ``"30 deg"``).
Angle = Annotated[float, BeforeValidator(_to_radians), AfterValidator(_finite)]
#: A point or vector in metres.
Vec3 = tuple[Coordinate, Coordinate, Coordinate]
#: A finite plain number (no unit conversion).
Finite = Annotated[float, AfterValidator(_finite)]
