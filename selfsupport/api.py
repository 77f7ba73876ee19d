"""A thin convenience layer over scenes, methods and the equilibrium check.

Two calls cover the usual jobs::

    >>> from selfsupport import api
    >>> from selfsupport.core.shapes import make_shape
    >>> res = api.solve(make_shape("dome", n_vertices=300))
    >>> res.status, res.max_relative_error < 1e-9
    ('converged', True)
    >>> api.check(res.network).self_supporting
    True

* :func:`solve` reads a scene (or takes one), builds the self-weight load case, picks a method
  from :data:`METHODS` by name and returns its :class:`~selfsupport.core.result.SolveResult`.
* :func:`check` keeps the positions as they are, fits the weights with the staggered method's
  Step 2 (same scaling, same bounds, same backend) and says whether the surface stands:
  a :class:`CheckReport`.

Methods are named in :data:`~selfsupport.methods.METHODS` (re-exported here) and imported only
when used; what each can do is its :class:`~selfsupport.methods.Capabilities`.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from formulations import Planar, Problem
from selfsupport.core.defaults import DEFAULT_CHECK_TOL, DEFAULT_DENSITY, DEFAULT_THICKNESS
from selfsupport.core.errors import InputError
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.result import Network, SolveResult
from selfsupport.core.scene import Scene
from selfsupport.core.triangulation import SPLIT_RULE, split_scene
from selfsupport.io import read_mesh, read_network
from selfsupport.io.loadcases import LoadSpec
from selfsupport.io.network_json import load_case_entries
from selfsupport.io.problem import load_spec, problem, scene_loads, weight_bounds
from selfsupport.io.scenes import as_scene, design_of
from selfsupport.methods import METHODS, MethodSpec, make_method, method_class
from selfsupport.methods.choice import AUTO
from selfsupport.methods.fixed_fit import fit_weights
from selfsupport.methods.solve import solve as solve_scene
from selfsupport.remesh.planar import solve_planar

__all__ = ["AUTO", "METHODS", "MethodSpec", "method_class", "make_method", "solve", "check", "CheckReport", "problem",
           "weight_bounds", "load_spec", "as_scene", "design_of", "triangulated_design", "scene_loads", "sensitivity", "koebe",
           "DEFAULT_DENSITY",
           "DEFAULT_THICKNESS", "DEFAULT_CHECK_TOL"]

#: The modules imported where used, not at the top (a named exception to the layout rule,
#: tests/test_layout.py): a solve does not load the IPOPT machinery of sensitivities nor the Koebe
#: family's analysis.
_LAZY = ("selfsupport.methods.sensitivity", "selfsupport.analysis.koebe")



def solve(scene_or_path: Scene | str | os.PathLike, *, constraints: Any = (), planar_finish: bool = True,
          time_limit: float | None = None, started: float | None = None, triangulate: bool = False,
          **kw: Any) -> SolveResult:
    """Find the thrust network nearest to a reference surface: :func:`selfsupport.methods.solve.solve`
    (every keyword is its own), and with planar faces the planar finish.

    Planar faces (a :class:`formulations.Planar` among ``constraints``) are held as a penalty by the
    staggered and multilevel methods, which may stall before the faces are planar; where they do
    not converge, :func:`selfsupport.remesh.planar.solve_planar` finishes from the network in
    equilibrium without planar faces (the planar homotopy, then IPOPT), as ``selfsupport solve
    --planar`` does. ``parameters["planar_finish"]`` says how it ended (``None``: the first method
    alone).

    Parameters
    ----------
    scene_or_path, constraints, time_limit, started, **kw
        As :func:`selfsupport.methods.solve.solve`; ``time_limit`` holds for the finish too.
    planar_finish
        Run the planar finish where the first solve with planar faces does not converge
        (``False``: that solve alone).
    triangulate
        Split the design's faces into triangles first (:func:`triangulated_design`; ``supports``
        and ``up`` among ``kw`` apply to the file). A scene :func:`triangulated_design` made is
        recorded either way: ``parameters["triangulated"]`` gives the faces before and after.

    Returns
    -------
    SolveResult

    Examples
    --------
    >>> from formulations import Planar
    >>> from selfsupport.core.shapes import make_shape
    >>> res = solve(make_shape("barrel_vault", nx=6, ny=8), constraints=[Planar(tol=1e-3)])
    >>> res.status, res.parameters["planarity"]["met"]
    ('converged', True)
    """
    planar = [c for c in constraints or () if isinstance(c, Planar)]
    if triangulate:
        scene_or_path = triangulated_design(scene_or_path, supports=kw.pop("supports", None), up=kw.pop("up", None))
    split = scene_or_path.meta.get("triangulated") if isinstance(scene_or_path, Scene) else None
    if split is not None and planar:
        raise InputError("planar faces (--planar) are quads kept planar, and a triangulated mesh has none (its "
                         "triangles are planar already); drop --planar or --triangulate")
    if not planar:
        res = solve_scene(scene_or_path, constraints=constraints, time_limit=time_limit, started=started, **kw)
        return res if split is None else replace(res, parameters={**res.parameters, "triangulated": dict(split)})
    t0 = time.perf_counter() if started is None else float(started)
    limit = None if time_limit is None else max(float(time_limit) - (time.perf_counter() - t0), 1e-3)
    others = [c for c in constraints if not isinstance(c, Planar)]
    return solve_planar(scene_or_path, tol=min(c.tol for c in planar), method=kw.pop("method", AUTO),
                        finish=planar_finish, time_limit=limit, equilibrium_tol=kw.pop("tol", None),
                        constraints=others, **kw)


def triangulated_design(scene_or_path: Scene | str | os.PathLike, *, supports: Any = None,
                        up: str | None = None) -> Scene:
    """The design of a scene (:func:`design_of`) with every face split into triangles by
    :func:`~selfsupport.core.triangulation.split_scene`: the same vertices, supports and vertex
    loads, every original edge kept and a diagonal added per extra triangle.

    Edge data follow the edges by their two vertices: a ``.sss`` file's edge weights stay on the
    kept edges (a diagonal is written with 0), and bounds from a file (``bounds=``) or a
    stress (``max_stress=``) are stated for the split mesh when the solve builds them, the
    diagonals taking the defaults. A network file's stored network does not start the solve (its
    faces are not split): it starts from the split reference, as ``meta["design"]["start"]`` says.
    ``meta["triangulated"]`` records the faces before and after.

    >>> from selfsupport.core.shapes import make_shape
    >>> triangulated_design(make_shape("barrel_vault", nx=4, ny=3)).meta["triangulated"]
    {'faces': 12, 'triangles': 24, 'edges': 31, 'edges_after': 43, 'rule': 'shortest diagonals (quads: the shorter one)'}
    """
    scene, stored = design_of(as_scene(scene_or_path, supports=supports, up=up))
    split = split_scene(scene)
    record = {"faces": scene.mesh.n_faces, "triangles": split.mesh.n_faces, "edges": scene.mesh.n_edges,
              "edges_after": split.mesh.n_edges, "rule": SPLIT_RULE}
    meta = {**split.meta, "triangulated": record}
    if stored is not None:
        meta["design"] = {**meta.get("design", {}), "start": "the stored reference triangulated (the stored network's "
                                                              "faces are not split)"}
    return replace(split, meta=meta)


# ------------------------------------------------------------------------------- scenes
@dataclass(frozen=True, eq=False)
class CheckReport:
    """Is a surface self-supporting as it is? (see :func:`check`)

    ``max_relative_error``, ``E``, ``min_weight``, ``n_at_lower`` (weights at or below ε)
    describe the best compressive weights fitted at fixed positions with loads computed from
    the geometry; ``self_supporting`` is ``max_relative_error <= tol`` with all of them >= 0;
    ``stored_*`` describe the weights a network file already carried (``None`` otherwise);
    ``stored_self_supporting`` is their own verdict: max relative error with the stored loads
    ``<= tol`` and no weight below 0.
    """

    name: str
    n_vertices: int
    n_edges: int
    n_supports: int
    self_supporting: bool
    tol: float
    max_relative_error: float
    E: float
    min_weight: float
    n_at_lower: int
    eps: float
    fit_status: str
    total_load: float
    seconds: float
    network: Network  # the fitted network (current positions, fitted weights, recomputed loads)
    stored_max_relative_error: float | None = None  # stored weights with the stored loads
    stored_max_relative_error_recomputed: float | None = None  # stored weights with recomputed loads
    stored_min_weight: float | None = None
    cases: tuple[dict[str, Any], ...] = ()  # per load case (several cases only): name, errors, min weights
    stored_self_supporting: bool | None = None
    case_networks: tuple[tuple[str, Network], ...] = ()  # per load case (several cases only): the fitted network
    load_model: Mapping[str, Any] | None = None  # the loads checked (LoadSpec.describe)

    def rows(self) -> list[tuple[str, str]]:
        """(label, value) pairs for a summary table."""
        r = [("input", self.name), ("vertices", str(self.n_vertices)), ("edges", str(self.n_edges)),
             ("supports", str(self.n_supports)), ("total load", f"{self.total_load:.6g} N"),
             ("fitted weights: max relative error", f"{self.max_relative_error:.3e}"),
             ("fitted weights: E", f"{self.E:.3e}"),
             ("fitted weights: min weight", f"{self.min_weight:.4g} N/m"),
             ("fitted weights: at or below eps", f"{self.n_at_lower} (eps = {self.eps:.3g} N/m)")]
        if self.stored_max_relative_error is not None:
            r += [("stored weights: max relative error (stored loads)", f"{self.stored_max_relative_error:.3e}"),
                  ("stored weights: max relative error (recomputed loads)",
                   f"{self.stored_max_relative_error_recomputed:.3e}"),
                  ("stored weights: min weight", f"{self.stored_min_weight:.4g} N/m"),
                  ("stored weights: self-supporting", f"{'yes' if self.stored_self_supporting else 'NO'} "
                                                      f"(tol {self.tol:g}, stored loads)")]
        for c in self.cases:
            r.append((f"case {c['name']}: max relative error (fitted / stored)",
                      f"{c['max_relative_error']:.3e} / {c.get('stored_max_relative_error_recomputed', float('nan')):.3e}"))
        r += [("fitted weights: self-supporting", f"{'yes' if self.self_supporting else 'NO'} (tol {self.tol:g})"),
              ("time", f"{self.seconds:.2f} s")]
        return r

    def file_fields(self) -> dict[str, Any]:
        """The keys a network file of the fitted weights (:attr:`network`) carries beside the
        network: ``status`` (``"self_supporting"`` when :attr:`self_supporting`, else
        ``"not_self_supporting"``), ``method`` ``"check"``, the evidence, the loads checked
        (``parameters.load_model``, so that checking the file again uses them) and, with several
        load cases, each case's fitted weights (``load_cases``)."""

        d: dict[str, Any] = {
            "status": "self_supporting" if self.self_supporting else "not_self_supporting", "method": "check",
            "tol": self.tol, "max_relative_error": self.max_relative_error, "min_weight": self.min_weight,
            "check": {"fit_status": self.fit_status, "E": self.E, "eps": self.eps, "n_at_lower": self.n_at_lower,
                      "seconds": self.seconds},
            "parameters": {"load_model": dict(self.load_model or {})},
        }
        if self.case_networks:
            d["load_cases"] = load_case_entries(self.case_networks)
        return d


def _stored_document(path: Path) -> dict[str, Any]:
    """The raw JSON of a network file (for its load model and per-case weights), or ``{}``."""

    try:
        d = json.loads(path.read_text(encoding="utf-8"))
        return d if isinstance(d, dict) else {}
    except (OSError, ValueError, RecursionError):
        return {}


def _stored_load_model(doc: Mapping[str, Any]) -> dict[str, Any]:
    """The load model a network file was solved with (``parameters.load_model``, or the older
    ``parameters.loads`` with ρ and t only), if any."""
    params = doc.get("parameters", {})
    if not isinstance(params, dict):
        return {}
    model = params.get("load_model") or params.get("loads") or {}
    return model if isinstance(model, dict) else {}


def check(obj: Scene | Network | PolyMesh | str | os.PathLike, *, supports: Any = None, up: str | None = None,
          density: float | None = None, thickness: float | None = None, tol: float = DEFAULT_CHECK_TOL,
          eps: Any = None, w_max: Any = None, backend: str = "active-set") -> CheckReport:
    """Fit compressive weights to a surface as it is (positions fixed) and report whether it
    is self-supporting: for every load case, ``max relative error <= tol`` with all weights
    >= 0 and loads of its own geometry (see :func:`~selfsupport.methods.fixed_fit.fit_weights`).

    Parameters
    ----------
    obj
        A mesh/scene/network file or object (see :func:`as_scene`). For a :class:`Network` or a
        ``.json`` network file the stored weights are also evaluated as they are (each load
        case's, when the file has several).
    supports, up
        See :func:`as_scene`.
    density, thickness
        Self-weight model; ``None`` takes it from the network file's load model when there is
        one (with its point loads, extra masses and load cases), else the defaults (2000 kg/m³,
        0.1 m). The verdict does not depend on them for pure self-weight (weights scale with the
        load), the reported weights do.
    tol
        Max relative error that counts as self-supporting.
    eps, w_max, backend
        Weight bounds [N/m] and the Step-2 backend, as in the staggered method.
    """

    t0 = time.perf_counter()
    stored: Network | None = None
    doc: dict[str, Any] = {}
    if isinstance(obj, Network):
        stored = obj
    elif isinstance(obj, (str, os.PathLike)) and Path(obj).suffix.lower() == ".json":

        doc = _stored_document(Path(obj))
        if "weights" in doc or "edges" in doc:  # not a hand-made {"vertices", "faces", "supports"} scene
            stored = read_network(obj)  # a malformed network is an input error, not a scene
    scene = as_scene(obj, supports=supports, up=up)
    scene.mesh.validate()
    scene.check_supports()
    model = dict(_stored_load_model(doc))
    if density is not None:
        model["density"] = density
    if thickness is not None:
        model["thickness"] = thickness
    spec = LoadSpec.from_description(model)
    prob = Problem.build(scene, spec.cases(scene.mesh.n_vertices), eps=eps, w_max=w_max)
    V = scene.mesh.vertices
    L = prob.loads.nodal(scene.mesh, V)
    stored_cases = {c.get("name"): c for c in doc.get("load_cases", []) if isinstance(c, dict)}
    stored_w: list[np.ndarray | None] = []  # per load case, the file's own weights (if it has them)
    for k, name in enumerate(prob.loads.names):
        sw = None
        if stored is not None and stored.mesh.n_vertices == scene.mesh.n_vertices:
            sw = stored.weights if k == 0 else None
            if name in stored_cases and len(stored_cases[name].get("weights", [])) == scene.mesh.n_edges:
                sw = np.asarray(stored_cases[name]["weights"], float)
        stored_w.append(sw)
    fits = fit_weights(prob, L, backend=backend)
    starts = [sw[scene.active_edges] if sw is not None and sw.size == scene.mesh.n_edges else None for sw in stored_w]
    if any(w is not None for w in starts):
        # The fit from eps can stall above tol where the file's weights are in equilibrium, and
        # the verdict would deny what the file proves: fit from those weights too, and keep the
        # better fit of each case. eps (which only keeps fits off zero) comes down to their
        # smallest weight: the solve computed its eps on the reference, and weights clipped to
        # this geometry's eps stall like the fit from eps.
        floor = min(float(w.min(initial=np.inf)) for w in starts if w is not None)
        loose = eps is None and 0.0 < floor < fits[0].eps
        prob_s = replace(prob, bounds=replace(prob.bounds, lower=floor)) if loose else prob
        again = fit_weights(prob_s, L, backend=backend, start=starts)
        fits = [b if w is not None and b.relative_errors.max(initial=0.0) < a.relative_errors.max(initial=0.0) else a
                for a, b, w in zip(fits, again, starts)]
    cases, nets = [], []
    for k, (name, fit, sw) in enumerate(zip(prob.loads.names, fits, stored_w)):
        weights = np.zeros(scene.mesh.n_edges)
        weights[scene.active_edges] = fit.weights
        net = Network(mesh=scene.mesh, weights=weights, loads=L[k], supports=scene.supports, handles=scene.handles)
        row = {"name": name, "max_relative_error": net.max_relative_error(), "min_weight": net.min_weight()}
        if sw is not None:
            row["stored_max_relative_error_recomputed"] = Network(mesh=stored.mesh, weights=sw, loads=L[k],
                                                                  supports=scene.supports).max_relative_error()
            row["stored_min_weight"] = Network(mesh=stored.mesh, weights=sw, loads=L[k],
                                               supports=scene.supports).min_weight()
        cases.append(row)
        nets.append(net)
    rel = max(c["max_relative_error"] for c in cases)  # the evidence, recomputed from the networks
    min_w = min(c["min_weight"] for c in cases)
    kw: dict[str, Any] = {}
    if stored is not None and stored.mesh.n_vertices == scene.mesh.n_vertices:
        sup = scene.supports
        kw["stored_max_relative_error"] = Network(mesh=stored.mesh, weights=stored.weights, loads=stored.loads,
                                                  supports=sup).max_relative_error()
        kw["stored_max_relative_error_recomputed"] = max(c.get("stored_max_relative_error_recomputed", -np.inf)
                                                         for c in cases)
        kw["stored_min_weight"] = min(c.get("stored_min_weight", np.inf) for c in cases)
        kw["stored_self_supporting"] = bool(kw["stored_max_relative_error"] <= tol
                                            and all(c.get("stored_max_relative_error_recomputed", 0.0) <= tol
                                                    for c in cases[1:])
                                            and kw["stored_min_weight"] >= 0)
    return CheckReport(name=scene.name, n_vertices=scene.mesh.n_vertices, n_edges=scene.mesh.n_edges,
                       n_supports=int(scene.supports.sum()), self_supporting=bool(rel <= tol and min_w >= 0),
                       tol=float(tol), max_relative_error=rel, E=float(sum(f.E for f in fits)), min_weight=min_w,
                       n_at_lower=int(sum(f.n_at_lower for f in fits)), eps=fits[0].eps, fit_status=fits[0].status,
                       total_load=float(L[0].sum()), seconds=time.perf_counter() - t0, network=nets[0],
                       cases=tuple(cases) if len(cases) > 1 else (), load_model=spec.describe(),
                       case_networks=tuple(zip(prob.loads.names, nets)) if len(nets) > 1 else (), **kw)


# -------------------------------------------------------------------------- sensitivity
def sensitivity(result: Any, parameter: str, *, problem: Problem | None = None) -> Any:
    """dV/dθ and dw/dθ of a converged ``method="ipopt"`` solve with respect to one parameter
    (``"density"``, ``"thickness"``, ``"w_max"``, ``"point_load:V"``, ``"objective:NAME"``): a
    :class:`~selfsupport.methods.sensitivity.Sensitivity` (SI units). ``problem``: the solved
    problem (default: rebuilt from the result's parameters). See
    :func:`selfsupport.methods.sensitivity.sensitivity`."""
    from selfsupport.methods.sensitivity import sensitivity as _sensitivity  # (see _LAZY)

    return _sensitivity(result, parameter, problem=problem)


# ------------------------------------------------------------------------------ Koebe family
def koebe(source: PolyMesh | str | os.PathLike = "enneper", *, alpha: float = 1.0, kind: str = "tangent",
          up: str | None = None, load_density: float = 1.0, loads: str = "reciprocal", koenigs_tol: float = 1e-8,
          **grid: Any) -> Any:
    """A member of the paper's §5 family ``Φ + αR`` (Fig. 15) as a thrust network.

    ``source`` is the Koebe mesh Φ: a built-in example name (``selfsupport.analysis.koebe.
    KOEBE_EXAMPLES``; ``kind`` and the ``grid`` keywords ``n``, ``hole``, ``mobius``, ``spacing``
    of :func:`~selfsupport.analysis.koebe.koebe_mesh` apply), a mesh file (read with ``up``) or a
    :class:`PolyMesh`. A dome (the thrust network of α = 0) is reflected into the convex Φ first.
    ``koenigs_tol`` is the largest Koenigs defect accepted for Φ's polar mesh (rounded files need more).
    Returns a :class:`~selfsupport.analysis.koebe.KoebeFamily`; its ``network`` is in equilibrium
    for every α with loads ``−q A*_i`` (see :mod:`selfsupport.analysis.koebe`).

    >>> fam = koebe("enneper", alpha=2.0, n=8, hole=2)
    >>> fam.network.max_relative_error() < 1e-10
    True
    """
    from selfsupport.analysis.koebe import KOEBE_EXAMPLES, as_airy, family, koebe_mesh, minimal_partner  # (see _LAZY)

    if isinstance(source, PolyMesh):
        mesh = source
    elif isinstance(source, str) and source in KOEBE_EXAMPLES:
        mesh = koebe_mesh(source, kind=kind, **grid)
    else:
        if grid:
            raise InputError(f"grid keywords {sorted(grid)} only apply to the built-in examples "
                             f"({', '.join(KOEBE_EXAMPLES)})")
        if not Path(source).exists():
            raise InputError(f"{source}: no such file, and not a Koebe example ({', '.join(KOEBE_EXAMPLES)})")
        mesh = read_mesh(source, up=up)
    phi, flipped = as_airy(mesh)
    partner = minimal_partner(phi, tol=koenigs_tol)
    return replace(family(phi, alpha, partner=partner, load_density=load_density, loads=loads), flipped=flipped)
