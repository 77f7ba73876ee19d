"""The compas form diagram of the shared problem, and the force densities read back from it:
shared by the compas-tna and compas-tno runners (compas is imported only in the peers' environment)."""
from __future__ import annotations

from typing import Any

import numpy as np


def form_diagram(P: dict[str, Any], pz: np.ndarray) -> tuple[Any, Any]:
    """``(form, mesh)``: the problem's mesh as a compas ``FormDiagram``, its supports marked, ``pz``
    per vertex in the tool's own sign convention (the caller's conversion), edges between
    boundary supports dropped (``update_boundaries``)."""
    from compas.datastructures import Mesh
    from compas_tna.diagrams import FormDiagram

    mesh = Mesh.from_vertices_and_faces(P["vertices"].tolist(), P["faces"])
    form = FormDiagram.from_mesh(mesh)
    form.vertices_attribute("is_support", True, keys=[int(i) for i in P["supports"]])
    for i in range(len(P["vertices"])):
        form.vertex_attributes(i, ["px", "py", "pz"], [0.0, 0.0, float(pz[i])])
    form.update_boundaries()
    return form, mesh


def read_back(form: Any, P: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The form's vertex positions (a vertex it dropped keeps the problem's) and its ``q`` per
    problem edge, in the tool's own sign (0 on an edge it dropped)."""
    V = P["vertices"]
    X = np.array([form.vertex_coordinates(i) if form.has_vertex(i) else V[i].tolist() for i in range(len(V))], float)
    q = {(min(u, v), max(u, v)): float(form.edge_attribute((u, v), "q")) for u, v in form.edges_where(_is_edge=True)}
    return X, np.array([q.get((min(a, b), max(a, b)), 0.0) for a, b in P["edges"]], float)
