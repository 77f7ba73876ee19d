"""Design operations of the paper's §4: edit the reference, then re-solve (warm).

* :mod:`.laplacian` — handle deformation with Laplacian coordinates (full, height-only,
  top-view-only), one factorization per region of interest;
* :mod:`.edits` — raise/lower, pillars, pin/unpin, cuts and holes, material and load changes,
  each a small class in the :data:`~selfsupport.design.edits.EDITS` registry;
* :mod:`.subdivision` — Catmull–Clark for polygon meshes with boundaries and creases;
* :mod:`.script` — the TOML edit-script format and its replay (``selfsupport edit``);
* :mod:`.session` — an interactive session: edit log with undo / redo, warm solves in a background
  thread (newest edit wins); :mod:`.server` puts it on a local web page (``selfsupport design``).
"""
from selfsupport.design.laplacian import LaplacianEditor, laplacian_matrix, ring_region

__all__ = ["LaplacianEditor", "laplacian_matrix", "ring_region"]
