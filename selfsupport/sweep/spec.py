"""Sweep definitions: a TOML file -> frozen dataclasses -> the list of runs.

A sweep file names scenes, methods, parameter grids, repetitions, a per-run time budget and
the report wanted::

    [sweep]
    name = "small"
    scenes = ["shape:dome?n_vertices=300",            # a built-in shape (selfsupport.core.shapes)
              "vault.sss",                            # a file, relative to the scene folder
              {path = "structural.obj", supports = "structural.supports", up = "-y"}]
    scene_dir = "../../shared/paper-scenes/scenes"    # relative to this file (optional)
    methods = ["staggered", "staggered:osqp", "ipopt"]   # method[:backend] (selfsupport.api.METHODS)
    repetitions = 1
    time_budget = 60.0        # seconds per run, passed to the method as its time limit
    grace = 20.0              # the hard backstop fires at time_budget + grace

    [grid]                    # cartesian product (a scalar is a one-value list)
    density = [1000.0, 2000.0, 4000.0]
    w_max = ["none", 2e4]

    [zip]                     # equal-length lists walked together, crossed with the grid
    thickness = [0.1, 0.2]
    tol = [1e-9, 1e-8]

    [options.staggered]       # method options, a grid that applies to that method's runs only
    alpha0 = [1.0, 100.0]

    [report]
    table = ["scene", "method", "w_max"]             # group-by columns of the summary table
    plots = [{kind = "line", x = "density", y = "max_rel_error", hue = "method", facet = "scene"},
             {kind = "time_vs_size"}, {kind = "success_rate"}]

Run parameters (:data:`PARAMETERS`): ``density`` [kg/m³], ``thickness`` [m], ``w_max`` and
``eps`` [N/m] (``"none"``: no bound / the method's default), ``tol``, ``max_iter``, ``objective``
(``"reference=1 planarity=10"``: terms of :data:`formulations.TERMS` and their weights;
``"default"``: the method's own). The scene
folder is, in order of precedence: the ``scene_dir`` argument of :func:`load_spec` (CLI
``--scenes``), the environment variable :data:`SCENES_ENV`, ``[sweep] scene_dir`` (relative to
the sweep file), the sweep file's own folder.

Every problem raises :class:`~selfsupport.core.errors.InputError` with the file and what to fix.
"""
from __future__ import annotations

import hashlib
import inspect
import itertools
import math
import os
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Callable, Mapping
from urllib.parse import parse_qsl

from formulations import parse_objective
from selfsupport.api import METHODS
from selfsupport.core.errors import InputError, SelfSupportError
from selfsupport.core.scene import Scene
from selfsupport.core.shapes import SHAPES, make_shape
from selfsupport.io import read_scene
from selfsupport.io.supports import SUPPORT_RULES
from selfsupport.sweep.report import PLOTS
from selfsupport.sweep.store import COLUMN_NAMES

__all__ = ["SCENES_ENV", "PARAMETERS", "SceneRef", "MethodRef", "PlotSpec", "ReportSpec", "RunSpec",
           "SweepSpec", "load_spec", "parse_spec", "parse_scene_ref"]

#: Environment variable naming the scene folder (below ``--scenes``, above ``scene_dir``).
SCENES_ENV = "SELFSUPPORT_SCENES"

_NONE_WORDS = {"none", "null", "off", "inf", "infinity"}


# ---------------------------------------------------------------------------- parameter types
def _positive_float(name: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError(f"parameter {name} must be a number, got {v!r}")
    v = float(v)
    if not (math.isfinite(v) and v > 0):
        raise InputError(f"parameter {name} must be a positive finite number, got {v!r}")
    return v


def _optional_bound(name: str, v: Any) -> float | None:
    """A bound in N/m, or None for "no bound" (TOML has no null: ``"none"`` or ``inf``)."""
    if isinstance(v, str) and v.strip().lower() in _NONE_WORDS:
        return None
    if isinstance(v, float) and math.isinf(v) and v > 0:
        return None
    return _positive_float(name, v)


def _optional_count(name: str, v: Any) -> int | None:
    if isinstance(v, str) and v.strip().lower() in _NONE_WORDS:
        return None
    if isinstance(v, bool) or not isinstance(v, int) or v < 1:
        raise InputError(f"parameter {name} must be a positive integer or \"none\", got {v!r}")
    return int(v)


def _objective(name: str, v: Any) -> str | None:
    """An objective as ``"NAME=W NAME=W"`` (terms of :data:`formulations.TERMS`), or ``"default"``
    / ``"none"`` for the method's own; kept as a normalised string (a table column)."""
    if not isinstance(v, str):
        raise InputError(f"parameter {name} must be a string such as \"reference=1 planarity=10\", got {v!r}")
    if v.strip().lower() in _NONE_WORDS | {"default"}:
        return None

    terms = parse_objective(v.replace(",", " ").split())
    return " ".join(f"{t.name}={t.weight:g}" for t in terms)


@dataclass(frozen=True)
class Parameter:
    """A run parameter: how to check a value, and its value when the sweep does not set it."""

    convert: Callable[[str, Any], Any]
    default: Any
    doc: str


#: The run parameters a sweep may vary (``[grid]`` / ``[zip]``); every run has all of them.
PARAMETERS: dict[str, Parameter] = {
    "density": Parameter(_positive_float, 2000.0, "material density ρ [kg/m³]"),
    "thickness": Parameter(_positive_float, 0.1, "shell thickness t [m]"),
    "w_max": Parameter(_optional_bound, None, "upper weight bound [N/m] (none: unbounded)"),
    "eps": Parameter(_optional_bound, None, "lower weight bound [N/m] (none: the scale-free default)"),
    "tol": Parameter(_positive_float, 1e-9, "required max relative error"),
    "max_iter": Parameter(_optional_count, None, "iteration limit (none: the method's default)"),
    "objective": Parameter(_objective, None, "objective terms \"NAME=W ...\" (default: the method's own)"),
}


# ---------------------------------------------------------------------------- methods
# The sweep's methods are the command line's (selfsupport.api.METHODS: staggered, ipopt, ...).
# solve() keywords the sweep sets itself: an option may not override them.
_RESERVED = {"scene", "loads", "eps", "w_max", "tol", "max_iter", "time_limit", "progress", "warm_start", "self",
             "backend"}


def split_options(cls: type, options: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Method options -> (constructor keywords, solve keywords): a name that is an explicit
    keyword of ``cls.solve`` goes to ``solve``, anything else to the constructor (the
    staggered method's :class:`StaggeredOptions`, IPOPT options of the simultaneous one)."""
    params = inspect.signature(cls.solve).parameters
    solve_kw = {n for n, p in params.items() if p.kind is p.KEYWORD_ONLY or p.kind is p.POSITIONAL_OR_KEYWORD}
    solve_kw -= _RESERVED
    return ({k: v for k, v in options.items() if k not in solve_kw},
            {k: v for k, v in options.items() if k in solve_kw})


@dataclass(frozen=True)
class MethodRef:
    """``method[:backend]`` from the sweep file; ``backend`` is resolved to the method's
    default when the method has a backend choice, None when it has none."""

    method: str
    backend: str | None

    @property
    def label(self) -> str:
        return self.method if self.backend is None else f"{self.method}:{self.backend}"


def parse_method_ref(text: Any, where: str) -> MethodRef:

    if not isinstance(text, str) or not text.strip():
        raise InputError(f"{where}: a method is a string like \"staggered\" or \"staggered:osqp\", got {text!r}")
    name, _, backend = text.strip().partition(":")
    spec = METHODS.get(name)
    if spec is None:
        raise InputError(f"{where}: unknown method {name!r}; known methods: {', '.join(METHODS)}")
    cls = spec.load()  # an unavailable method stops the sweep before it starts, with the reason
    names = spec.backend_names()
    if backend and backend not in names:
        raise InputError(f"{where}: method {name!r} has " + (f"no backend {backend!r}; choose one of {list(names)}"
                                                              if names else "no backend choice; write just the name"))
    if names and not backend:
        default = inspect.signature(cls.__init__).parameters.get("backend")
        backend = default.default if default is not None and isinstance(default.default, str) else None
    return MethodRef(name, backend or None)


# ---------------------------------------------------------------------------- scenes
def _coerce(text: str) -> Any:
    """Query-string value -> int, float, bool or str (``n_vertices=300`` is an int)."""
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


@dataclass(frozen=True)
class SceneRef:
    """One scene of a sweep: a built-in shape with parameters, or a file.

    ``kind`` is a key of :data:`SCENE_LOADERS`. ``label`` names the scene in tables and plots.
    """

    kind: str
    label: str
    shape: str | None = None
    shape_params: tuple[tuple[str, Any], ...] = ()
    path: Path | None = None
    supports: str | None = None
    up: str | None = None

    def load(self) -> Scene:
        """Build or read the scene (raises :class:`InputError` / ``MeshError`` if it cannot)."""
        return SCENE_LOADERS[self.kind](self)


def _load_shape(ref: SceneRef) -> Scene:
    return make_shape(ref.shape, **dict(ref.shape_params))


def _load_file(ref: SceneRef) -> Scene:
    return read_scene(ref.path, up=ref.up, supports=ref.supports, name=ref.label)


#: scene kind -> loader
SCENE_LOADERS: dict[str, Callable[[SceneRef], Scene]] = {"shape": _load_shape, "file": _load_file}


def parse_scene_ref(item: Any, scene_dir: Path, where: str) -> SceneRef:
    """``"shape:NAME?k=v&..."``, ``"file.sss"`` or ``{path=..., supports=..., up=..., name=...}``.

    Relative file paths (and supports files) resolve against ``scene_dir``; nothing is read here.
    """
    if isinstance(item, str) and item.startswith("shape:"):
        body = item[len("shape:"):]
        name, _, query = body.partition("?")
        if name not in SHAPES:
            raise InputError(f"{where}: unknown shape {name!r} in {item!r}; known shapes: {', '.join(sorted(SHAPES))}")
        try:
            pairs = parse_qsl(query, keep_blank_values=False, strict_parsing=bool(query))
        except ValueError:
            raise InputError(f"{where}: cannot parse the parameters of {item!r}; write shape:NAME?key=value&key=value") from None
        params = tuple(sorted((k, _coerce(v)) for k, v in pairs))
        return SceneRef(kind="shape", label=body, shape=name, shape_params=params)
    if isinstance(item, str):
        item = {"path": item}
    if not isinstance(item, dict) or not isinstance(item.get("path"), str):
        raise InputError(f"{where}: a scene is \"shape:NAME?...\", a file name, or a table with a path, got {item!r}")
    unknown = set(item) - {"path", "supports", "up", "name"}
    if unknown:
        raise InputError(f"{where}: unknown scene key(s) {sorted(unknown)}; use path, supports, up, name")
    path = Path(item["path"]).expanduser()
    path = path if path.is_absolute() else scene_dir / path
    supports = item.get("supports")
    if supports is not None:
        if supports not in SUPPORT_RULES:
            sp = Path(supports).expanduser()
            supports = str(sp if sp.is_absolute() else scene_dir / sp)
    return SceneRef(kind="file", label=str(item.get("name") or path.stem), path=path, supports=supports,
                    up=item.get("up"))


# ---------------------------------------------------------------------------- report
@dataclass(frozen=True)
class PlotSpec:
    """One plot of the report. ``kind`` is a key of :data:`selfsupport.sweep.report.PLOTS`;
    ``x``, ``y``, ``hue``, ``facet`` are result columns (None = the kind's default); ``status``
    keeps only the runs with these statuses (e.g. ``["converged"]``)."""

    kind: str
    x: str | None = None
    y: str | None = None
    hue: str | tuple[str, ...] | None = None
    facet: str | None = None
    logx: bool | None = None
    logy: bool | None = None
    title: str | None = None
    file: str | None = None
    status: tuple[str, ...] | None = None  # only runs with these statuses (e.g. ["converged"])


@dataclass(frozen=True)
class ReportSpec:
    table: tuple[str, ...] = ("scene", "method")
    plots: tuple[PlotSpec, ...] = (PlotSpec("success_rate"), PlotSpec("time_vs_size"))


def _parse_report(raw: Any, where: str) -> ReportSpec:

    if raw is None:
        return ReportSpec()
    if not isinstance(raw, dict):
        raise InputError(f"{where}: [report] must be a table")
    unknown = set(raw) - {"table", "plots"}
    if unknown:
        raise InputError(f"{where}: unknown [report] key(s) {sorted(unknown)}; use table, plots")

    def column(name: Any, what: str) -> str:
        if name not in COLUMN_NAMES:
            raise InputError(f"{where}: [report] {what} {name!r} is not a result column; columns: {', '.join(COLUMN_NAMES)}")
        return name

    table = tuple(column(c, "table column") for c in raw.get("table", ReportSpec.table))
    plots = []
    known = {f.name for f in fields(PlotSpec)}
    for k, p in enumerate(raw.get("plots", [{"kind": p.kind} for p in ReportSpec.plots])):
        if not isinstance(p, dict) or "kind" not in p:
            raise InputError(f"{where}: [report] plots[{k}] must be a table with a kind")
        if p["kind"] not in PLOTS:
            raise InputError(f"{where}: [report] plots[{k}]: unknown kind {p['kind']!r}; known: {', '.join(sorted(PLOTS))}")
        bad = set(p) - known
        if bad:
            raise InputError(f"{where}: [report] plots[{k}]: unknown key(s) {sorted(bad)}; use {', '.join(sorted(known))}")
        for key in ("x", "y", "facet"):
            if p.get(key) is not None:
                column(p[key], f"plots[{k}].{key}")
        if p.get("status") is not None:
            st = p["status"]
            p = {**p, "status": (st,) if isinstance(st, str) else tuple(st)}
        if isinstance(p.get("hue"), list):  # several columns: one line per combination
            p = {**p, "hue": tuple(column(c, f"plots[{k}].hue") for c in p["hue"])}
        elif p.get("hue") is not None:
            column(p["hue"], f"plots[{k}].hue")
        plots.append(PlotSpec(**p))
    return ReportSpec(table=table, plots=tuple(plots))


# ---------------------------------------------------------------------------- runs
@dataclass(frozen=True)
class RunSpec:
    """One solve of the sweep. ``params`` holds every :data:`PARAMETERS` entry (defaults
    filled in, values normalised) so that equal runs compare and hash equal."""

    scene: SceneRef
    method: str
    backend: str | None
    params: tuple[tuple[str, Any], ...]
    options: tuple[tuple[str, Any], ...]
    repetition: int
    time_budget: float

    @property
    def param_dict(self) -> dict[str, Any]:
        return dict(self.params)

    @property
    def option_dict(self) -> dict[str, Any]:
        return dict(self.options)

    def identity(self) -> dict[str, Any]:
        """What determines the result, apart from the scene content (the time budget does not:
        it is how long we are willing to wait, not what we ask)."""
        return {"method": self.method, "backend": self.backend, "params": self.param_dict,
                "options": self.option_dict, "repetition": self.repetition}


@dataclass(frozen=True)
class SweepSpec:
    """A parsed sweep file. :meth:`expand` lists its runs."""

    name: str
    source: Path | None
    text: str
    scene_dir: Path
    scenes: tuple[SceneRef, ...]
    methods: tuple[MethodRef, ...]
    grid: tuple[tuple[str, tuple[Any, ...]], ...]
    zipped: tuple[tuple[str, tuple[Any, ...]], ...]
    options: tuple[tuple[str, tuple[tuple[str, tuple[Any, ...]], ...]], ...]
    repetitions: int = 1
    time_budget: float = 300.0
    grace: float = field(default=0.0)
    report: ReportSpec = field(default_factory=ReportSpec)

    @property
    def digest(self) -> str:
        return hashlib.sha256(self.text.encode()).hexdigest()

    @property
    def hard_limit(self) -> float:
        """Seconds after a run starts at which the runner gives up on it (budget + grace)."""
        return self.time_budget + self.grace

    def expand(self) -> tuple[RunSpec, ...]:
        """All runs: scenes × methods × grid × zip rows × method options × repetitions."""
        names = [n for n, _ in self.grid]
        grid_rows = [dict(zip(names, combo)) for combo in itertools.product(*(v for _, v in self.grid))]
        znames = [n for n, _ in self.zipped]
        zvalues = [v for _, v in self.zipped]
        zip_rows = [dict(zip(znames, vals)) for vals in zip(*zvalues)] if zvalues else [{}]
        method_opts = dict(self.options)
        runs = []
        for scene in self.scenes:
            for m in self.methods:
                ogrid = method_opts.get(m.method, ())
                onames = [n for n, _ in ogrid]
                opt_rows = [tuple(zip(onames, c)) for c in itertools.product(*(v for _, v in ogrid))]
                for g in grid_rows:
                    for z in zip_rows:
                        merged = {n: p.default for n, p in PARAMETERS.items()} | g | z
                        params = tuple(sorted(merged.items()))
                        for o in opt_rows:
                            for rep in range(self.repetitions):
                                runs.append(RunSpec(scene=scene, method=m.method, backend=m.backend,
                                                    params=params, options=tuple(sorted(o)), repetition=rep,
                                                    time_budget=self.time_budget))
        return tuple(runs)


def _value_list(name: str, raw: Any, convert: Callable[[str, Any], Any] | None, where: str) -> tuple[Any, ...]:
    values = raw if isinstance(raw, list) else [raw]
    if not values:
        raise InputError(f"{where}: {name} has an empty list of values; give at least one")
    try:
        out = tuple(convert(name, v) if convert else v for v in values)
    except InputError as e:
        raise InputError(f"{where}: {e}") from None
    if len(set(map(repr, out))) != len(out):
        raise InputError(f"{where}: {name} lists a value twice: {list(values)}")
    return out


def _param_table(raw: Any, section: str, where: str) -> tuple[tuple[str, tuple[Any, ...]], ...]:
    if raw is None:
        return ()
    if not isinstance(raw, dict):
        raise InputError(f"{where}: [{section}] must be a table of parameter = [values]")
    out = []
    for name, vals in raw.items():
        p = PARAMETERS.get(name)
        if p is None:
            raise InputError(f"{where}: [{section}] unknown parameter {name!r}; known: {', '.join(PARAMETERS)} "
                             "(method options go in [options.METHOD])")
        out.append((name, _value_list(name, vals, p.convert, f"{where}: [{section}]")))
    return tuple(out)


def _check_options(method: str, sample: dict[str, Any], where: str) -> None:
    """Build the method once with the options so that unknown names fail now, not in every run."""

    cls = METHODS[method].load()
    ctor, _ = split_options(cls, sample)
    try:
        cls(**ctor)
    except SelfSupportError as e:
        raise InputError(f"{where}: {e}") from None
    except TypeError as e:
        raise InputError(f"{where}: {e}") from None


def _number(raw: dict, key: str, default: float, where: str, minimum: float = 0.0) -> float:
    v = raw.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < minimum:
        raise InputError(f"{where}: [sweep] {key} must be a finite number >= {minimum:g}, got {v!r}")
    return float(v)


def parse_spec(text: str, *, source: Path | None = None, scene_dir: str | Path | None = None) -> SweepSpec:
    """Parse sweep TOML ``text`` (``source`` is the file it came from, for messages and
    relative paths). See the module docstring for the format."""
    where = str(source) if source else "sweep"
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"{where}: not valid TOML: {e}") from None
    unknown = set(raw) - {"sweep", "grid", "zip", "options", "report"}
    if unknown:
        raise InputError(f"{where}: unknown section(s) {sorted(unknown)}; use [sweep], [grid], [zip], [options.METHOD], [report]")
    sw = raw.get("sweep")
    if not isinstance(sw, dict):
        raise InputError(f"{where}: missing [sweep] table (name, scenes, methods, ...)")
    bad = set(sw) - {"name", "description", "scenes", "scene_dir", "methods", "repetitions", "time_budget", "grace"}
    if bad:
        raise InputError(f"{where}: unknown [sweep] key(s) {sorted(bad)}")
    base = source.parent if source else Path.cwd()
    if scene_dir is None:
        scene_dir = os.environ.get(SCENES_ENV) or None
    if scene_dir is None and sw.get("scene_dir"):
        scene_dir = base / Path(sw["scene_dir"]).expanduser()
    sdir = Path(scene_dir).expanduser() if scene_dir is not None else base
    sdir = sdir if sdir.is_absolute() else Path.cwd() / sdir

    scenes_raw = sw.get("scenes")
    if not isinstance(scenes_raw, list) or not scenes_raw:
        raise InputError(f"{where}: [sweep] scenes must be a non-empty list")
    scenes = tuple(parse_scene_ref(s, sdir, f"{where}: scenes[{k}]") for k, s in enumerate(scenes_raw))
    labels = [s.label for s in scenes]
    dup = sorted({x for x in labels if labels.count(x) > 1})
    if dup:
        raise InputError(f"{where}: scene label(s) {dup} appear twice; give one of them a name = \"...\"")
    methods_raw = sw.get("methods", ["staggered"])
    methods_raw = methods_raw if isinstance(methods_raw, list) else [methods_raw]
    methods = tuple(parse_method_ref(m, f"{where}: methods[{k}]") for k, m in enumerate(methods_raw))
    if len({m.label for m in methods}) != len(methods):
        raise InputError(f"{where}: [sweep] methods lists a method twice")

    grid = _param_table(raw.get("grid"), "grid", where)
    zipped = _param_table(raw.get("zip"), "zip", where)
    both = {n for n, _ in grid} & {n for n, _ in zipped}
    if both:
        raise InputError(f"{where}: parameter(s) {sorted(both)} are in both [grid] and [zip]; keep each in one")
    lengths = {n: len(v) for n, v in zipped}
    if len(set(lengths.values())) > 1:
        raise InputError(f"{where}: [zip] lists must have equal lengths, got {lengths}")

    opts_raw = raw.get("options") or {}
    if not isinstance(opts_raw, dict):
        raise InputError(f"{where}: [options] must hold tables [options.METHOD]")
    options = []
    for mname, table in opts_raw.items():
        if mname not in {m.method for m in methods}:
            raise InputError(f"{where}: [options.{mname}]: {mname!r} is not one of the sweep's methods "
                             f"({', '.join(m.method for m in methods)})")
        if not isinstance(table, dict):
            raise InputError(f"{where}: [options.{mname}] must be a table of option = [values]")
        bad = sorted(set(table) & _RESERVED)
        if bad:
            raise InputError(f"{where}: [options.{mname}] sets {bad}, which the sweep sets itself; "
                             "use [grid] / [zip] (tol, max_iter, eps, w_max) or [sweep] time_budget")
        grid_o = tuple((o, _value_list(o, v, None, f"{where}: [options.{mname}]")) for o, v in sorted(table.items()))
        _check_options(mname, {o: v[0] for o, v in grid_o}, f"{where}: [options.{mname}]")
        options.append((mname, grid_o))

    reps = sw.get("repetitions", 1)
    if isinstance(reps, bool) or not isinstance(reps, int) or reps < 1:
        raise InputError(f"{where}: [sweep] repetitions must be a positive integer, got {reps!r}")
    budget = _number(sw, "time_budget", 300.0, where, minimum=1e-3)
    grace = _number(sw, "grace", 10.0 + 0.1 * budget, where)
    name = sw.get("name") or (source.stem if source else "sweep")
    return SweepSpec(name=str(name), source=source, text=text, scene_dir=sdir, scenes=scenes, methods=methods,
                     grid=grid, zipped=zipped, options=tuple(options), repetitions=reps, time_budget=budget,
                     grace=grace, report=_parse_report(raw.get("report"), where))


def load_spec(path: str | Path, *, scene_dir: str | Path | None = None) -> SweepSpec:
    """Read and check a sweep file (see the module docstring). ``scene_dir`` overrides the
    scene folder (CLI ``--scenes``)."""
    path = Path(path).expanduser()
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise InputError(f"cannot read sweep file {path}: {e.strerror or e}") from None
    return parse_spec(text, source=path.resolve(), scene_dir=scene_dir)
