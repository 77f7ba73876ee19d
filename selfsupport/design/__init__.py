"""Design operations of the paper's §4: edit the reference, then re-solve (warm).

* :mod:`.laplacian` — handle deformation with Laplacian coordinates (full, height-only,
  top-view-only), one factorization per region of interest;
* :mod:`.edits` — raise/lower, pillars, pin/unpin, cuts and holes, material and load changes,
  each a small class in the :data:`~selfsupport.design.edits.EDITS` registry;
* :mod:`.script` — the TOML edit-script format and its replay (``selfsupport edit``).

Catmull–Clark subdivision is :mod:`selfsupport.core.subdivision`; the interactive design tool
(edit log with undo / redo, warm solves in a background thread, the local web page of
``selfsupport design``) is :mod:`selfsupport.app`.
"""
from selfsupport.design.laplacian import LaplacianEditor, laplacian_matrix, ring_region

__all__ = ["LaplacianEditor", "laplacian_matrix", "ring_region"]
