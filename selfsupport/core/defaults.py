"""Default values the command line states in its help, in a module that imports nothing, so that
building the parser loads no numpy (:mod:`selfsupport.api` re-exports them)."""
from __future__ import annotations

__all__ = ["DEFAULT_DENSITY", "DEFAULT_THICKNESS", "DEFAULT_CHECK_TOL"]

#: Default material: stone-like density [kg/m³] and shell thickness [m] (the paper's examples).
DEFAULT_DENSITY = 2000.0
DEFAULT_THICKNESS = 0.1
#: Max relative error below which ``check`` calls a surface self-supporting.
DEFAULT_CHECK_TOL = 1e-6
