"""selfsupport: design of self-supporting masonry surfaces (Vouga et al., SIGGRAPH 2012)."""
from .errors import (BackendUnavailable, InfeasibleDesign, InputError, MeshError,
                     SelfSupportError, SupportError)
from .loads import CombinedLoad, ExtraMass, LoadCase, PointLoad, SelfWeight
from .mesh import PolyMesh
from .scene import Scene

__version__ = "0.1.0"
