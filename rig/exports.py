"""The names a package lets users import, each loaded from the module that defines it on first use.

A package's `__init__` maps each name in its `__all__` to its defining module and sets
`__getattr__ = lazy_names(__name__, NAMES)` (PEP 562): `from rig.runner import execute_run` works,
yet importing a package imports none of its modules, so no import cost and no import cycle starts
in an `__init__`. Code inside the rig imports from the defining modules themselves.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_names(package: str, names: Mapping[str, str]) -> Callable[[str], Any]:
    """A module `__getattr__` for `package` that loads `name` from `package.names[name]`."""

    def load(name: str) -> Any:
        module = names.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(f"{package}.{module}"), name)

    return load
