"""A thin convenience layer over scenes, methods and the equilibrium check.

Two calls cover the usual jobs::

    >>> from selfsupport import api
    >>> from selfsupport.shapes import make_shape
    >>> res = api.solve(make_shape("dome", n_vertices=300))            # doctest: +SKIP
    >>> res.status, res.max_relative_error < 1e-9                      # doctest: +SKIP
    ('converged', True)
    >>> api.check(res.network).self_supporting                         # doctest: +SKIP
    True

* :func:`solve` reads a scene (or takes one), builds the self-weight load case, picks a method
  from :data:`METHODS` by name and returns its :class:`~selfsupport.result.SolveResult`.
* :func:`check` keeps the positions as they are, fits the weights with the staggered method's
  Step 2 (same scaling, same bounds, same backend) and says whether the surface stands:
  a :class:`CheckReport`.

Methods are named in :data:`METHODS` and imported only when used (the IPOPT method pulls in
CasADi; a method whose module is not installed yet raises
:class:`~selfsupport.errors.BackendUnavailable` with the reason instead of breaking the import).
"""
from __future__ import annotations

import importlib
import os
import time
from contextlib import nullcontext
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import scipy.sparse as sp

from .errors import BackendUnavailable, InputError
from .loads import G, LoadCase, SelfWeight, with_scene_extras
from .mesh import PolyMesh
from .result import Network, SolveResult
from .scene import Scene
from .validate import validate_scene

__all__ = ["METHODS", "MethodSpec", "method_class", "make_method", "solve", "check", "CheckReport",
           "as_scene", "scene_loads", "require_finite_loads", "fit_weights", "DEFAULT_DENSITY", "DEFAULT_THICKNESS", "DEFAULT_CHECK_TOL"]

#: Default material: stone-like density [kg/m³] and shell thickness [m] (the paper's examples).
DEFAULT_DENSITY = 2000.0
DEFAULT_THICKNESS = 0.1
#: Max relative error below which :func:`check` calls a surface self-supporting.
DEFAULT_CHECK_TOL = 1e-6


# ------------------------------------------------------------------------------ methods
@dataclass(frozen=True)
class MethodSpec:
    """Where a method class lives, so that it is imported only when asked for.

    Attributes
    ----------
    module, attr
        ``importlib.import_module(module).<attr>`` is the method class; its instances have
        ``solve(scene, loads, *, eps, w_max, progress, tol, max_iter, time_limit) -> SolveResult``.
    summary
        One line for ``--help``.
    backends
        Name of a module-level dict of backend names in ``backend_module`` (the method's
        constructor then takes ``backend=NAME``); empty when the method has no backend choice.
    """

    module: str
    attr: str
    summary: str
    backend_module: str = ""
    backends: str = ""

    def load(self) -> type:
        """Import and return the method class; :class:`BackendUnavailable` if it is not there."""
        try:
            mod = importlib.import_module(self.module)
        except ModuleNotFoundError as e:
            # Only a missing *method* module is "unavailable"; a missing dependency inside an
            # existing module is reported the same way, with its name, so the user can install it.
            raise BackendUnavailable(f"method module {self.module} cannot be imported ({e}); "
                                     f"choose another --method (one of {', '.join(METHODS)})") from None
        try:
            return getattr(mod, self.attr)
        except AttributeError:
            raise BackendUnavailable(f"{self.module} has no {self.attr} yet; choose another --method "
                                     f"(one of {', '.join(METHODS)})") from None

    def backend_names(self) -> tuple[str, ...]:
        """Backend names the method accepts (empty: no choice)."""
        if not self.backends:
            return ()
        return tuple(getattr(importlib.import_module(self.backend_module), self.backends))


#: Method name (``--method``) -> where its class lives.
METHODS: dict[str, MethodSpec] = {
    "staggered": MethodSpec("selfsupport.methods.staggered", "StaggeredLinearization",
                            "the paper's staggered linearization (§3): weights and positions in turn",
                            backend_module="selfsupport.methods.weightfit", backends="WEIGHT_FIT_BACKENDS"),
    "ipopt": MethodSpec("selfsupport.methods.simultaneous", "Simultaneous",
                        "all positions and weights at once with IPOPT (CasADi, MUMPS)"),
    "nlopt": MethodSpec("selfsupport.methods.nlopt_methods", "NloptSimultaneous",
                        "all positions and weights at once with nlopt SLSQP (small problems only)"),
}


def method_class(name: str) -> type:
    """The method class registered as ``name`` in :data:`METHODS` (imported now)."""
    try:
        spec = METHODS[name]
    except KeyError:
        raise InputError(f"unknown method {name!r}; choose one of {', '.join(METHODS)}") from None
    return spec.load()


def make_method(name: str = "staggered", backend: str | None = None) -> Any:
    """An instance of method ``name``; ``backend`` picks its inner solver where it has a choice
    (the staggered method's Step 2: see ``selfsupport.methods.weightfit.WEIGHT_FIT_BACKENDS``)."""
    cls = method_class(name)
    if backend is None:
        return cls()
    names = METHODS[name].backend_names()
    if not names:
        raise InputError(f"method {name!r} has no backend choice; leave --backend out")
    if backend not in names:
        raise InputError(f"unknown backend {backend!r} for method {name!r}; choose one of {', '.join(names)}")
    return cls(backend=backend)


# ------------------------------------------------------------------------------- scenes
def _supports_mask(spec: Any, mesh: PolyMesh, source: str) -> np.ndarray:
    """``spec`` as a boolean mask: ``"boundary"`` / a supports file / indices / a mask."""
    if isinstance(spec, (str, os.PathLike)):
        from .io.supports import resolve_supports

        return np.asarray(resolve_supports(spec, mesh, source=source), bool)
    a = np.asarray(spec)
    if a.dtype == bool:
        if a.shape != (mesh.n_vertices,):
            raise InputError(f"supports mask has shape {a.shape} for {mesh.n_vertices} vertices")
        return a.copy()
    idx = a.astype(np.int64).ravel()
    if idx.size and (idx.min() < 0 or idx.max() >= mesh.n_vertices):
        raise InputError(f"support index outside 0..{mesh.n_vertices - 1}")
    m = np.zeros(mesh.n_vertices, bool)
    m[idx] = True
    return m


def as_scene(obj: Scene | Network | PolyMesh | str | os.PathLike, *, supports: Any = None,
             up: str | None = None) -> Scene:
    """A :class:`Scene` from a scene, a network, a mesh or a file.

    Parameters
    ----------
    obj
        A :class:`Scene` (``supports`` replaces its own if given); a :class:`Network` (its current
        geometry and supports); a :class:`PolyMesh` (needs ``supports``); or a path read with
        :func:`selfsupport.io.read_scene` (``.sss``, ``.obj``, ``.ply``, ``.off``, ``.json``).
    supports
        ``"boundary"``, a supports file, vertex indices or a boolean mask.
    up
        The file's vertical axis (files only; ``None`` = the format's convention).
    """
    if isinstance(obj, (str, os.PathLike)):
        from .io import read_scene

        if supports is None or isinstance(supports, (str, os.PathLike)):
            return read_scene(obj, up=up, supports=None if supports is None else str(supports))
        scene = read_scene(obj, up=up, supports="boundary")  # placeholder, replaced just below
        return replace(scene, supports=_supports_mask(supports, scene.mesh, str(obj)))
    if up is not None:
        raise InputError("up= only applies to files; rotate the mesh yourself for in-memory input")
    if isinstance(obj, Scene):
        if supports is None:
            return obj
        return replace(obj, supports=_supports_mask(supports, obj.mesh, obj.name))
    if isinstance(obj, Network):
        sup = obj.supports if supports is None else _supports_mask(supports, obj.mesh, "network")
        return Scene(mesh=obj.mesh, supports=sup, handles=obj.handles, name="network")
    if isinstance(obj, PolyMesh):
        if supports is None:
            raise InputError("a bare mesh has no supports; pass supports='boundary', a supports file or indices")
        return Scene(mesh=obj, supports=_supports_mask(supports, obj, "mesh"), name="mesh")
    raise InputError(f"cannot make a scene of a {type(obj).__name__}; pass a Scene, Network, PolyMesh or a file path")


def scene_loads(scene: Scene, *, density: float = DEFAULT_DENSITY, thickness: float = DEFAULT_THICKNESS) -> LoadCase:
    """Self-weight ρ·t·g plus the scene's extra masses and point loads."""
    for name, v in (("density", density), ("thickness", thickness)):
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"{name} must be a positive number, got {v}")
    return with_scene_extras(SelfWeight(density=float(density), thickness=float(thickness)), scene)


#: Largest nodal load magnitude [N] the arithmetic takes: forces are squared in norms and in the
#: fits (1e150² = 1e300, below the double range 1.8e308), and the smallest nonzero one.
LOAD_LIMIT = 1e150


def require_finite_loads(scene: Scene, loads: LoadCase) -> None:
    """Raise :class:`InputError` when the nodal loads at the reference overflow (or vanish in)
    floating-point arithmetic — e.g. ``density=1e300`` — instead of letting the solve end in
    ``inf``/``nan`` and a misleading "stalled"."""
    with np.errstate(all="ignore"):
        L = np.asarray(loads.nodal(scene.mesh, scene.mesh.vertices), float)
        big = float(np.max(np.abs(L))) if L.size else 0.0
    if not np.isfinite(L).all() or big > LOAD_LIMIT:
        raise InputError(f"the loads overflow floating-point arithmetic (largest nodal load {big:.3g} N, the limit "
                         f"is {LOAD_LIMIT:.0e} N: squared forces would be non-finite); check the units of --density, "
                         "--thickness and the extra loads")
    if not big > 1.0 / LOAD_LIMIT:
        raise InputError(f"the loads vanish in floating-point arithmetic (largest nodal load {big:.3g} N, below "
                         f"{1 / LOAD_LIMIT:.0e} N); check the units of --density, --thickness and the mesh")


# -------------------------------------------------------------------------------- solve
def solve(scene_or_path: Scene | str | os.PathLike, *, method: str = "staggered", backend: str | None = None,
          density: float = DEFAULT_DENSITY, thickness: float = DEFAULT_THICKNESS, w_max: float | None = None,
          eps: float | None = None, tol: float | None = None, max_iter: int | None = None,
          time_limit: float | None = None, supports: Any = None, up: str | None = None,
          progress: Callable[[dict], None] | None = None, options: Mapping[str, Any] | None = None) -> SolveResult:
    """Find the thrust network nearest to a reference surface.

    Parameters
    ----------
    scene_or_path
        A :class:`Scene` or a scene/mesh file (see :func:`as_scene`).
    method
        A name in :data:`METHODS`: ``"staggered"`` (default), ``"ipopt"``, ``"nlopt"``.
    backend
        The method's inner solver, where it has a choice (staggered: Step-2 backend,
        default ``"active-set"``).
    density, thickness
        Self-weight ρ [kg/m³] and t [m]; the load is ρ·t·g per unit surface area.
    w_max, eps
        Upper and lower weight bounds [N/m] (``None``: no upper bound / the scale-free default).
    tol, max_iter, time_limit
        Stopping rules; ``None`` keeps the method's defaults (staggered: ``tol`` is the required
        max relative error, ``max_iter`` counts outer iterations; IPOPT: its ``tol`` and its
        iteration limit per load round).
    supports, up
        See :func:`as_scene`.
    progress
        Called with each iteration's history record.
    options
        Further settings of the staggered method (fields of
        :class:`~selfsupport.methods.staggered.StaggeredOptions`, e.g. ``{"coupled": True}``).

    Returns
    -------
    SolveResult
        Its ``parameters`` gain ``"loads"`` (the self-weight model) so the file can be re-checked,
        and ``"input_issues"``: the warnings of :func:`~selfsupport.validate.validate_scene` as dicts.

    Raises
    ------
    MeshError, SupportError, InputError
        Unusable input (see :func:`~selfsupport.validate.validate_scene`), before any solving.
    """
    scene = as_scene(scene_or_path, supports=supports, up=up)
    issues = validate_scene(scene)  # raises for unusable input before any work; warnings go into the result
    loads = scene_loads(scene, density=density, thickness=thickness)
    require_finite_loads(scene, loads)
    stops = {k: v for k, v in (("tol", tol), ("max_iter", max_iter), ("time_limit", time_limit)) if v is not None}
    if options:
        if method != "staggered":
            raise InputError(f"method options {sorted(options)} apply to the staggered method only, not {method!r}")
        from .methods.staggered import StaggeredOptions
        from .options import check_options

        check_options(StaggeredOptions, options)  # before the work, with the allowed interval
        stops = {**dict(options), **stops}
    solver = make_method(method, backend)
    # a support that belongs to no face has no neighbours: its umbrella-Laplacian row divides by 0 (harmlessly)
    quiet = np.errstate(divide="ignore") if any(i.code == "isolated_vertices" for i in issues) else nullcontext()
    with quiet:
        result = solver.solve(scene, loads, eps=eps, w_max=w_max, progress=progress, **stops)
    load_model = {"type": "self_weight", "density": float(density), "thickness": float(thickness), "g": G}
    return replace(result, parameters={**result.parameters, "loads": load_model,
                                       "input_issues": [i.as_dict() for i in issues]})


# -------------------------------------------------------------------------------- check
#: :func:`fit_weights` starts with the staggered method's proximal weight
#: (``StaggeredOptions.prox_w``, relative to the mean squared column norm of the scaled A) and
#: divides it by :data:`PROX_STEP` per refit down to :data:`PROX_FLOOR`: a continuation towards
#: the unregularised fit. Below ~1e-16 the normal equations' round-off (~1e-9 relative error)
#: dominates, and prox = 0 makes the interior-point fallback factor a singular matrix.
PROX_STEP = 100.0
PROX_FLOOR = 1e-16
#: Max relative error of a fit below which no further refinement is attempted.
REFINED = 1e-13


@dataclass(frozen=True, eq=False)
class WeightFitReport:
    """The Step-2 fit at fixed positions, in SI units."""

    weights: np.ndarray  # per active edge [N/m]
    relative_errors: np.ndarray  # per free vertex
    E: float  # Σ_i relative_error_i² (the staggered method's fit energy)
    eps: float  # lower weight bound used [N/m]
    n_at_lower: int
    n_at_upper: int
    status: str  # the backend's status
    iterations: int


def fit_weights(scene: Scene, loads: np.ndarray, *, eps: float | None = None, w_max: float | None = None,
                backend: str = "active-set") -> WeightFitReport:
    """Step 2 of the staggered method at the scene's positions: the best weights in
    ``[eps, w_max]`` for the given nodal loads, fitted to the *relative* residual, then
    corrected by LSMR (:func:`_refine`), which may leave some weights between 0 and ``eps``
    (still compressive) when that brings the network into equilibrium.

    Same units as :class:`~selfsupport.methods.staggered.StaggeredLinearization`: lengths /
    bounding-box diagonal, forces / mean nodal load (:class:`~selfsupport.methods.scaling.Scaling`),
    rows divided by ``|A_i F_i|``, the default ``eps`` of
    :func:`~selfsupport.methods.scaling.default_eps`, and the same small proximal term.
    """
    from .methods.assembly import load_vector, weight_matrix
    from .methods.scaling import ScaledProblem
    from .methods.staggered import StaggeredOptions
    from .methods.weightfit import make_backend

    prob = ScaledProblem.build(scene, loads, eps=eps, w_max=w_max)
    top, sc, X, L, lower, upper = prob.top, prob.scaling, prob.X, prob.L, prob.lower, prob.upper
    free = top.free
    A = weight_matrix(top, X)
    s = np.repeat(1.0 / np.abs(L[free]), 3)
    As = sp.diags(s) @ A
    bs = s * load_vector(top, L)
    col2 = float(np.asarray(As.multiply(As).sum(axis=0)).mean())
    rel_prox = [StaggeredOptions().prox_w]
    while rel_prox[-1] / PROX_STEP >= PROX_FLOOR * (1 - 1e-9):
        rel_prox.append(rel_prox[-1] / PROX_STEP)
    be = make_backend(backend)
    fit, rel, iterations = None, None, 0
    w0 = lower.copy()
    # The proximal term (needed: A has more columns than rows, so the plain fit has a face of
    # minimisers) biases the answer towards w0; in the staggered loop w0 is the previous iterate
    # and the bias fades, here it would not: on a solved barrel vault one fit leaves 6e-4 where
    # 1e-12 is attainable. So continue with a shrinking proximal weight, each fit warm-started
    # from the last, while that helps; then correct the residual with LSMR (see _refine).
    for rp in rel_prox:
        fit = be.fit(A=As, b=bs, lower=lower, upper=upper, w0=w0, prox=rp * col2)
        w0, iterations = fit.w, iterations + fit.iterations
        prev = rel
        rel = np.linalg.norm((As @ fit.w - bs).reshape(-1, 3), axis=1)
        if rel.size == 0 or rel.max() <= REFINED or (prev is not None and rel.max() > 0.5 * prev.max()):
            break  # exact enough, or the normal equations' floor: further stages do not help
    w = fit.w
    if rel.size and rel.max() > REFINED:
        w, rel = _refine(As, bs, w, lower, upper, rel)
    return WeightFitReport(weights=sc.weight_back(w), relative_errors=rel, E=float(rel @ rel),
                           eps=float(sc.weight_back(lower[0])), n_at_lower=int(np.sum(w <= lower)),
                           n_at_upper=int(np.sum(w >= upper)),
                           status=fit.status, iterations=iterations)


def _refine(A: sp.spmatrix, b: np.ndarray, w: np.ndarray, lower: np.ndarray, upper: np.ndarray,
            rel: np.ndarray, max_rounds: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares corrections of the weights off their bounds, by LSMR on A itself.

    The box fit works on the normal equations AᵀA, whose condition number is the square of
    A's; on networks that are in equilibrium to 1e-13 it stalls at relative errors of 1e-8
    (solved barrel vault, 300 vertices) to 4e-6 (solved lilium, weights spanning four orders
    of magnitude, several hundred of them at ε), returning an interior point. Here the weights
    the fit holds on a bound stay there; LSMR gives the minimum-norm correction of the others;
    a corrected weight that turns tensile (< 0) or exceeds ``upper`` is fixed at its bound and
    the correction repeated. The lower bound of this correction is 0, not ε: whether the
    surface stands is a question of compression, ε only keeps the fit away from degenerate
    zero weights. The corrected weights are kept only if they lower the max error.
    """
    from scipy.sparse.linalg import lsmr

    A = sp.csc_matrix(A)
    fixed = (w <= lower) | (w >= upper)
    best_w, best_rel = w, rel
    for _ in range(max_rounds):
        free = ~fixed
        if not free.any():
            break
        base = np.where(fixed, np.clip(w, lower, upper), w)
        d = lsmr(A[:, free], b - A @ base, atol=1e-16, btol=1e-16, maxiter=20 * int(free.sum()))[0]
        w2 = base.copy()
        w2[free] += d
        bad = free & ((w2 < 0) | (w2 > upper))
        if not bad.any():
            rel2 = np.linalg.norm((A @ w2 - b).reshape(-1, 3), axis=1)
            if rel2.max() < best_rel.max():
                best_w, best_rel = w2, rel2
            break
        fixed |= bad
        w = np.clip(w2, lower, upper)
    return best_w, best_rel


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
    stored_self_supporting: bool | None = None

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
        r += [("fitted weights: self-supporting", f"{'yes' if self.self_supporting else 'NO'} (tol {self.tol:g})"),
              ("time", f"{self.seconds:.2f} s")]
        return r


def _stored_load_model(path: Path) -> dict[str, Any]:
    """The self-weight model a network file was solved with (``parameters.loads``), if any."""
    import json

    try:
        d = json.loads(path.read_text(encoding="utf-8"))
        model = d.get("parameters", {}).get("loads", {})
        return model if isinstance(model, dict) else {}
    except (OSError, ValueError, AttributeError):
        return {}


def _has_network_keys(path: Path) -> bool:
    """Whether a JSON file claims to be a network (has ``weights`` or ``edges``), rather than a
    hand-made ``{"vertices", "faces", "supports"}`` scene."""
    import json

    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False  # the scene reader reports what is wrong with it
    return isinstance(d, dict) and ("weights" in d or "edges" in d)


def check(obj: Scene | Network | PolyMesh | str | os.PathLike, *, supports: Any = None, up: str | None = None,
          density: float | None = None, thickness: float | None = None, tol: float = DEFAULT_CHECK_TOL,
          eps: float | None = None, w_max: float | None = None, backend: str = "active-set") -> CheckReport:
    """Fit compressive weights to a surface as it is (positions fixed) and report whether it
    is self-supporting: ``max relative error <= tol`` with all weights >= 0 and loads of its
    own geometry (see :func:`fit_weights`).

    Parameters
    ----------
    obj
        A mesh/scene/network file or object (see :func:`as_scene`). For a :class:`Network` or a
        ``.json`` network file the stored weights are also evaluated as they are.
    supports, up
        See :func:`as_scene`.
    density, thickness
        Self-weight model; ``None`` takes it from the network file's ``parameters.loads`` when
        there is one, else the defaults (2000 kg/m³, 0.1 m). The verdict does not depend on
        them for pure self-weight (weights scale with the load), the reported weights do.
    tol
        Max relative error that counts as self-supporting.
    eps, w_max, backend
        Weight bounds [N/m] and the Step-2 backend, as in the staggered method.
    """
    t0 = time.perf_counter()
    stored: Network | None = None
    model: dict[str, Any] = {}
    if isinstance(obj, Network):
        stored = obj
    elif isinstance(obj, (str, os.PathLike)) and Path(obj).suffix.lower() == ".json":
        from .io import read_network

        if _has_network_keys(Path(obj)):
            stored = read_network(obj)  # a malformed network is an input error, not a scene
        model = _stored_load_model(Path(obj))
    scene = as_scene(obj, supports=supports, up=up)
    scene.mesh.validate()
    scene.check_supports()
    density = float(model.get("density", DEFAULT_DENSITY)) if density is None else density
    thickness = float(model.get("thickness", DEFAULT_THICKNESS)) if thickness is None else thickness
    case = scene_loads(scene, density=density, thickness=thickness)
    require_finite_loads(scene, case)
    loads = case.nodal(scene.mesh, scene.mesh.vertices)
    fit = fit_weights(scene, loads, eps=eps, w_max=w_max, backend=backend)
    weights = np.zeros(scene.mesh.n_edges)
    weights[scene.active_edges] = fit.weights
    net = Network(mesh=scene.mesh, weights=weights, loads=loads, supports=scene.supports, handles=scene.handles)
    rel = net.max_relative_error()  # the evidence, recomputed from the network itself
    kw: dict[str, Any] = {}
    if stored is not None and stored.mesh.n_vertices == scene.mesh.n_vertices:
        sup = scene.supports
        kw["stored_max_relative_error"] = Network(mesh=stored.mesh, weights=stored.weights, loads=stored.loads,
                                                  supports=sup).max_relative_error()
        kw["stored_max_relative_error_recomputed"] = Network(mesh=stored.mesh, weights=stored.weights, loads=loads,
                                                             supports=sup).max_relative_error()
        kw["stored_min_weight"] = Network(mesh=stored.mesh, weights=stored.weights, loads=loads,
                                          supports=sup).min_weight()
        kw["stored_self_supporting"] = bool(kw["stored_max_relative_error"] <= tol and kw["stored_min_weight"] >= 0)
    return CheckReport(name=scene.name, n_vertices=scene.mesh.n_vertices, n_edges=scene.mesh.n_edges,
                       n_supports=int(scene.supports.sum()), self_supporting=bool(rel <= tol and net.min_weight() >= 0), tol=float(tol),
                       max_relative_error=rel, E=fit.E, min_weight=net.min_weight(), n_at_lower=fit.n_at_lower,
                       eps=fit.eps, fit_status=fit.status, total_load=float(loads.sum()),
                       seconds=time.perf_counter() - t0, network=net, **kw)
