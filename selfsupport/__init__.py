"""selfsupport: design of self-supporting masonry surfaces (Vouga et al., SIGGRAPH 2012)."""
from selfsupport.core.errors import BackendUnavailable, InfeasibleDesign, InputError, MeshError, SelfSupportError, SupportError
from selfsupport.core.loads import CombinedLoad, ExtraMass, LoadCase, PointLoad, SelfWeight
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.scene import Scene

__version__ = "0.1.0"

__all__ = ["BackendUnavailable", "CombinedLoad", "ExtraMass", "InfeasibleDesign", "InputError", "LoadCase", "MeshError",
           "PointLoad", "PolyMesh", "Scene", "SelfSupportError", "SelfWeight", "SupportError", "__version__"]
