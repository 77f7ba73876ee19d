"""A module imported on its first use: for libraries that only some paths need at run time.

``ca = lazy_module("casadi")`` at the top of a module names CasADi without importing it; the
first attribute read (``ca.MX``) imports it, through :func:`importlib.import_module` (thread-safe,
and ``sys.modules`` is left as the import system keeps it). A plain staggered solve never builds
a symbolic expression, and CasADi costs ~0.04 s of its process's start-up.
"""
from __future__ import annotations

import importlib
from types import ModuleType
from typing import Any


class LazyModule:
    """Stands for the module ``name`` until an attribute is read, then forwards to it."""

    def __init__(self, name: str) -> None:
        self._name = name
        self._module: ModuleType | None = None

    def __getattr__(self, attr: str) -> Any:
        # (only reached for names this object lacks: the module's own attributes)
        module = self._module
        if module is None:
            module = self._module = importlib.import_module(self._name)
        return getattr(module, attr)

    def __repr__(self) -> str:
        return f"<lazy module {self._name!r} ({'imported' if self._module is not None else 'not imported yet'})>"


def lazy_module(name: str) -> Any:
    """``name`` (e.g. ``"casadi"``), imported when one of its attributes is first read.

    >>> m = lazy_module("colorsys")
    >>> m.rgb_to_hsv(1.0, 0.0, 0.0)
    (0.0, 1.0, 1.0)
    """
    return LazyModule(name)
