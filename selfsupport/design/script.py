"""Edit scripts: a TOML list of design edits, replayed with a solve after each.

::

    [start]                       # all optional
    scene = "shape:barrel_vault:600"   # a file (relative to the script) or a built-in shape;
                                       # `selfsupport edit --scene FILE` gives or replaces it
    density = 2000.0              # kg/m³
    thickness = 0.1               # m
    # w_max = 1e5                 # N/m

    [solve]                       # options of the staggered method (StaggeredOptions fields)
    tol = 1e-9
    # warm = false                # re-solve every stage from scratch

    [[edit]]
    op = "pillar"                 # a name in selfsupport.design.edits.EDITS
    select = { nearest = [0.5, 0.5], relative = true }
    hole = true

    [[edit]]
    op = "pin"
    select = { vertices = [3, 4] }
    solve = false                 # no solve after this edit: it joins the next stage

Stage 0 is the starting scene solved; every edit with a solve ends a stage. After stage 0 each
solve is warm-started from the previous stage's network (:mod:`selfsupport.methods.warm`) unless
``warm = false``. A ``subdivide`` stage goes up from the previous stage's network through the
intermediate steps, each started from the stress of the one below
(:class:`~selfsupport.methods.multilevel.Multilevel`). Replays are deterministic (no randomness
anywhere on the path).
"""
from __future__ import annotations

import math
import time
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Mapping

from selfsupport.core.errors import InputError
from selfsupport.design.edits import Design, Edit, _check_value, edit_from_dict
from selfsupport.io.scenes import load_scene
from selfsupport.methods.multilevel import solve_warm
from selfsupport.methods.staggered import StaggeredLinearization
from selfsupport.methods.warm import WarmStart

__all__ = ["EditScript", "Stage", "replay", "dumps_toml"]


@dataclass(frozen=True)
class EditScript:
    """A parsed edit script (see the module docstring)."""

    edits: tuple[Edit, ...]
    solve_after: tuple[bool, ...]
    scene: str | None = None
    density: float = 2000.0
    thickness: float = 0.1
    w_max: float | None = None
    solve: Mapping[str, Any] = field(default_factory=dict)
    base: Path | None = None  # the script's folder (relative scene paths)

    @classmethod
    def loads(cls, text: str, base: Path | None = None) -> "EditScript":
        try:
            d = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise InputError(f"edit script: {e}") from None
        unknown = set(d) - {"start", "solve", "edit"}
        if unknown:
            raise InputError(f"edit script: unknown section(s) {sorted(unknown)}; use [start], [solve], [[edit]]")
        start = dict(d.get("start", {}))
        bad = set(start) - {"scene", "density", "thickness", "w_max"}
        if bad:
            raise InputError(f"edit script [start]: unknown key(s) {sorted(bad)}")
        if "scene" in start:
            _check_value(start["scene"], str, "edit script [start]: scene")
        for key in ("density", "thickness", "w_max"):  # (positive finite numbers: kg/m³, m, N/m)
            if key in start:
                _check_value(start[key], float, f"edit script [start]: {key}")
                if not start[key] > 0:
                    raise InputError(f"edit script [start]: {key} must be positive, got {start[key]!r}")
        edits, after = [], []
        for k, e in enumerate(d.get("edit", [])):
            e = dict(e)
            where = f"edit script, [[edit]] number {k + 1}"
            solve = e.pop("solve", True)
            _check_value(solve, bool, f"{where}: solve")
            after.append(solve)
            try:
                edits.append(edit_from_dict(e))
            except TypeError as err:
                raise InputError(f"{where} ({e.get('op')}): {err}") from None
            except InputError as err:
                raise InputError(f"{where}: {err}") from None
        return cls(edits=tuple(edits), solve_after=tuple(after), scene=start.get("scene"),
                   density=float(start.get("density", 2000.0)), thickness=float(start.get("thickness", 0.1)),
                   w_max=None if start.get("w_max") is None else float(start["w_max"]),
                   solve=dict(d.get("solve", {})), base=base)

    @classmethod
    def read(cls, path: str | Path) -> "EditScript":
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except OSError as e:
            raise InputError(f"{p}: cannot read the edit script ({e.strerror})") from None
        return cls.loads(text, base=p.resolve().parent)

    def to_dict(self) -> dict[str, Any]:
        start: dict[str, Any] = {"density": self.density, "thickness": self.thickness}
        if self.scene is not None:
            start = {"scene": self.scene, **start}
        if self.w_max is not None:
            start["w_max"] = self.w_max
        edits = [{**e.to_dict(), **({} if s else {"solve": False})} for e, s in zip(self.edits, self.solve_after)]
        out: dict[str, Any] = {"start": start}
        if self.solve:
            out["solve"] = dict(self.solve)
        out["edit"] = edits
        return out

    def dumps(self) -> str:
        """The script as TOML (``EditScript.loads(s.dumps()) == s`` up to ``base``)."""
        return dumps_toml(self.to_dict())


@dataclass(frozen=True, eq=False)
class Stage:
    """One replayed stage: its edits, the design after them and the solve's result."""

    index: int
    edits: tuple[Edit, ...]
    design: Design
    result: Any  # SolveResult
    warm: bool
    edit_seconds: float


def _start_scene(script: EditScript, scene: Any) -> Any:
    if scene is not None:
        return load_scene(str(scene)) if isinstance(scene, (str, Path)) else scene
    if script.scene is None:
        raise InputError("the edit script names no [start] scene; pass one (--scene FILE or shape:NAME)")
    spec = script.scene
    if not spec.startswith("shape:") and script.base is not None and not Path(spec).is_absolute():
        spec = str(script.base / spec)
    return load_scene(spec)


def replay(script: EditScript, scene: Any = None, *, on_stage: Callable[[Stage], None] | None = None,
           warm: bool | None = None) -> list[Stage]:
    """Solve the start, then apply the edits in order with a (warm) solve after each stage.

    Parameters
    ----------
    script
        The parsed script.
    scene
        The starting scene (a :class:`~selfsupport.core.scene.Scene`, a file or ``shape:...``);
        default: the script's ``[start] scene``.
    on_stage
        Called with every finished :class:`Stage` (the CLI writes files there).
    warm
        Override the script's ``[solve] warm``.
    """

    opts = dict(script.solve)
    use_warm = bool(opts.pop("warm", True)) if warm is None else bool(warm)
    backend = opts.pop("backend", "active-set")
    method = StaggeredLinearization(backend=backend)
    design = Design(_start_scene(script, scene), density=script.density, thickness=script.thickness,
                    w_max=script.w_max)
    stages: list[Stage] = []
    pending: list[Edit] = []
    prev = None
    t_edit = 0.0

    def solve_stage(edits: tuple[Edit, ...]) -> None:
        nonlocal prev, design
        ws = WarmStart(prev.network) if (use_warm and prev is not None) else None
        res = solve_warm(method, design.problem(), dict(opts), warm_start=ws)
        st = Stage(index=len(stages), edits=edits, design=design, result=res, warm=ws is not None,
                   edit_seconds=t_edit)
        stages.append(st)
        prev = res
        design = replace(design, origin=None)  # the next stage's origins refer to this stage
        if on_stage:
            on_stage(st)

    solve_stage(())
    for e, s in zip(script.edits, script.solve_after):
        t0 = time.perf_counter()
        design = e.apply(design)
        t_edit += time.perf_counter() - t0
        pending.append(e)
        if s:
            solve_stage(tuple(pending))
            pending, t_edit = [], 0.0
    if pending:  # trailing edits without a solve still end in a stage
        solve_stage(tuple(pending))
    return stages


# ------------------------------------------------------------------------ TOML writing
def dumps_toml(d: Mapping[str, Any]) -> str:
    """A small TOML writer for edit scripts: top-level tables and arrays of tables whose values
    are strings, numbers, booleans, arrays and inline tables (no tomli-w dependency needed)."""
    lines: list[str] = []
    for key, value in d.items():
        if isinstance(value, list) and value and all(isinstance(v, Mapping) for v in value):
            for item in value:
                lines += ["", f"[[{key}]]"] + [f"{k} = {_value(v)}" for k, v in item.items()]
        elif isinstance(value, Mapping):
            lines += ["", f"[{key}]"] + [f"{k} = {_value(v)}" for k, v in value.items()]
        else:
            lines.append(f"{key} = {_value(value)}")
    return "\n".join(lines).lstrip("\n") + "\n"


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise InputError(f"cannot write {v} in an edit script")
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{k} = {_value(x)}" for k, x in v.items()) + "}"
    raise InputError(f"cannot write a {type(v).__name__} in an edit script")
