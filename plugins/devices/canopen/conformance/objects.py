"""The EDS's objects as the cases use them: every variable, which are process data, which are settings."""

from __future__ import annotations

from canopen import objectdictionary as od

from . import standard as cia
from .session import Session


def variables(dictionary: od.ObjectDictionary):
    """Every variable of a dictionary (the members of arrays and records included), in index order."""
    for index in sorted(dictionary.indices):
        obj = dictionary[index]
        if isinstance(obj, od.ODVariable):
            yield obj
        else:
            yield from (obj[sub] for sub in sorted(obj.subindices))


def process_input(var: od.ODVariable) -> bool:
    """A read-only, mappable object: the drive's state (its value is not a default)."""
    return var.pdo_mappable and var.access_type in ("ro", "rwr")


def signature_object(var: od.ODVariable) -> bool:
    """0x1010/0x1011 sub-indices 1-127: written only with their signatures (CiA 301 §7.5.2.13/14)."""
    return var.index in (0x1010, 0x1011) and var.subindex > 0


def name(var: od.ODVariable) -> str:
    return f"0x{var.index:04X}:{var.subindex}"


def pick_parameter(session: Session, node_id: int, lo: int, hi: int, exclude: tuple = ()):
    """A setting of indices ``lo``-``hi`` (writable, readable, an integer, not mappable: not process data;
    not the error history, a signature object or a PDO parameter) and a value other than its present one
    that the drive accepts (written here); returns (variable, old value, new value) or None."""
    dictionary = session.drive(node_id).dictionary
    for var in variables(dictionary):
        if not lo <= var.index <= hi or var.index in exclude or var.pdo_mappable:
            continue
        if not (var.writable and var.readable) or var.data_type not in cia.INTEGERS:
            continue
        if var.subindex == 0 and not isinstance(dictionary[var.index], od.ODVariable):
            continue  # a record's highest sub-index
        if signature_object(var) or var.index == 0x1003 or 0x1400 <= var.index <= 0x1BFF:
            continue
        raw = session.upload(node_id, var.index, var.subindex)
        if isinstance(raw, int):
            continue
        old = var.decode_raw(raw)
        low, high = cia.integer_range(var.data_type)
        low = var.min if var.min is not None else low
        high = var.max if var.max is not None else high
        candidates = [1000] if var.index == 0x1017 else [old + 1, old - 1]  # a heartbeat time: not a flood
        for value in candidates:
            if value == old or not low <= value <= high:
                continue
            if session.download(node_id, var.index, var.subindex, var.encode_raw(value)) is None:
                return var, old, value
    return None
