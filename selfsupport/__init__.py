"""selfsupport: design of self-supporting masonry surfaces (Vouga et al., SIGGRAPH 2012).

The names below are loaded when first used (PEP 562), so that ``selfsupport --help`` and the
command line's parser do not pay for numpy and scipy."""
from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: Public name -> the module that defines it.
_EXPORTS = {
    **dict.fromkeys(("BackendUnavailable", "InfeasibleDesign", "InputError", "MeshError", "SelfSupportError",
                     "SupportError"), "selfsupport.core.errors"),
    **dict.fromkeys(("CombinedLoad", "ExtraMass", "LoadCase", "PointLoad", "SelfWeight"), "selfsupport.core.loads"),
    "PolyMesh": "selfsupport.core.mesh",
    "Scene": "selfsupport.core.scene",
}

__all__ = [*sorted(_EXPORTS), "__version__"]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'selfsupport' has no attribute {name!r}")
