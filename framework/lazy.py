"""Public names imported at first use: PEP 562 ``__getattr__`` and ``__dir__`` for a package.

A package whose names pull in heavy libraries (a plugin's device class and its CAN stack, a planner and its
compiled kernels) lists them here instead of importing them, so that importing the package (the registry
loading every entry point, ``surgiplan --help``) costs nothing; the module that defines a name is imported
when the name is first read, and the name is then kept in the package. Type checkers and the import contracts
see the names through the package's ``if TYPE_CHECKING:`` imports.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(package: str, names: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of ``package`` whose public ``names`` map to the (relative) module
    that defines each: ``__getattr__, __dir__ = lazy_exports(__name__, {"SafePRM": ".planner"})``."""

    def __getattr__(name: str) -> Any:
        module = names.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module, package), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(names))

    return __getattr__, __dir__
