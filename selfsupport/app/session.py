"""An interactive design session: the edit log with undo / redo, and warm re-solves in the background.

This is the engine behind ``selfsupport design`` (:mod:`selfsupport.app.server` puts it on
a web page); it has no web code and is usable on its own.

* :class:`EditLog` — the edits so far (the paper's §4 operations, :mod:`.edits`) with undo /
  redo. A *drag* (the same ``drag`` id as the last edit) replaces the last edit instead of
  adding one, so dragging a handle leaves one ``move`` in the log. The log is an edit script
  (:mod:`.script`): what ``selfsupport edit`` replays gives the same designs.
* :class:`SolveWorker` — one background thread that solves the newest design it was given,
  warm-started from the last network it found (:mod:`selfsupport.methods.warm`). A newer
  request cancels an older solve at its next iteration (the solve's progress callback raises
  :class:`Superseded`), unless solves have been cancelled for ``max_stale`` seconds without a
  frame: then the running solve finishes and its frame is sent (a drag whose steps come faster than one solve
  would otherwise show nothing until it ends). Requests that arrive during a solve are
  coalesced to the newest one.
  The page never waits on it: results come back through a callback.
* :func:`frame_payload` / :func:`analysis_payload` — what is streamed to the page: the network
  coloured by force, the reference and the material (the page draws the hull band, reference
  ± t/2, from them), the Airy surface and the reciprocal diagram.

Example
-------
>>> import threading
>>> from selfsupport.core.shapes import make_shape
>>> from selfsupport.design.edits import Pin, Select
>>> log = EditLog(Design(make_shape("dome", n_vertices=80)))
>>> seq = log.apply(Pin(select=Select(vertices=(0,))))
>>> done = threading.Event(); frames = []
>>> worker = SolveWorker(lambda m: (frames.append(m), done.set()) if m["type"] == "frame" else None)
>>> worker.submit(seq, log.design); done.wait(60)
True
>>> frames[0]["seq"] == seq, frames[0]["status"]
(True, 'converged')
>>> log.undo() > seq, log.can_redo
(True, True)
>>> worker.close()
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, replace
from typing import Any, Callable, Mapping

import numpy as np

from selfsupport.core.errors import InputError, SelfSupportError
from selfsupport.core.evidence import triangulate
from selfsupport.design.edits import Design, Edit, Objective, check_values
from selfsupport.design.script import EditScript
from selfsupport.figures.render import airy_of, edge_forces, reciprocal_segments
from selfsupport.io.network_json import finite_or_none as _finite
from selfsupport.methods.deadline import out_of_time
from selfsupport.methods.multilevel import solve_warm
from selfsupport.methods.staggered import StaggeredLinearization
from selfsupport.methods.validate import validate_scene
from selfsupport.methods.warm import WarmStart
from selfsupport.structure.stability import max_load

__all__ = ["EditLog", "SolveWorker", "Superseded", "frame_payload", "analysis_payload", "SOLVE_DEFAULTS"]

#: Options of every interactive solve (fields of StaggeredOptions), written into the saved edit
#: script so that ``selfsupport edit`` replays with them: a solve that cannot finish in
#: ``time_limit`` ends with the network so far (the next edit starts from it); ``finish_try``
#: 1.0 keeps the warm start of a drag step that left the network up to 100% out of
#: equilibrium (a 1 cm step of one handle on an 8 m vault: 0.6) and polishes from it — one
#: iteration, 0.16-0.2 s at 1,225 vertices, where the default 0.1 falls back to a cold solve
#: (18 iterations, 1 s).
SOLVE_DEFAULTS: dict[str, Any] = {"time_limit": 30.0, "finish_try": 1.0}
#: Designs kept in memory besides checkpoints (older ones are replayed from a checkpoint).
_KEEP_RECENT = 16
_CHECKPOINT_EVERY = 32


class Superseded(Exception):
    """A newer request arrived: the running solve stops (raised from its progress callback)."""


# ------------------------------------------------------------------------------ edit log
class EditLog:
    """Edits applied to a start design, with undo / redo and drag replacement.

    Every change (edit, drag step, undo, redo) increments :attr:`seq`, the number the page's
    frames are matched against. Designs are kept for the last few edits and at checkpoints;
    others are recomputed by re-applying edits (edits are deterministic), so memory stays
    bounded however long the session runs (the edits themselves are a few hundred bytes each).
    """

    def __init__(self, start: Design, *, scene_spec: str | None = None,
                 solve: Mapping[str, Any] | None = None) -> None:
        self.start = start
        self.scene_spec = scene_spec
        self.solve = dict(solve or {})
        self.edits: list[Edit] = []
        self.redo_stack: list[Edit] = []
        self.seq = 0
        self._drag: str | None = None  # drag id of the last edit while it is being dragged
        self._designs: dict[int, Design] = {0: start}
        self._lock = threading.RLock()

    # -- state --------------------------------------------------------------------------
    def design_at(self, k: int) -> Design:
        """The design after the first ``k`` edits."""
        with self._lock:
            if k in self._designs:
                return self._designs[k]
            base = max(j for j in self._designs if j <= k)
            d = self._designs[base]
            for j in range(base, k):
                d = self._apply(self.edits[j], d)
            self._remember(k, d)
            return d

    @property
    def design(self) -> Design:
        """The current design."""
        return self.design_at(len(self.edits))

    @property
    def can_undo(self) -> bool:
        return bool(self.edits)

    @property
    def can_redo(self) -> bool:
        return bool(self.redo_stack)

    # -- changes --------------------------------------------------------------------------
    def apply(self, edit: Edit, *, drag: str | None = None, deadline: float | None = None) -> int:
        """Apply ``edit`` (raises :class:`~selfsupport.core.errors.InputError` and changes nothing when
        it does not apply). ``drag``: an id shared by the steps of one drag; a step with the id of
        the last edit replaces it. ``deadline``: a ``time.perf_counter()`` value; an edit that
        ends after it is dropped (InputError, nothing changed). Returns the new :attr:`seq`.

        The edit is computed outside the log's lock, so a long edit does not hold up undo / redo
        or other pages' edits; when the log changed meanwhile, the edit is refused (it was made
        on a design that is no longer the current one)."""
        check_values(edit.to_dict(), f"edit {edit.op!r}")  # nothing unsendable enters the log

        def target() -> tuple[bool, int]:
            replacing = drag is not None and drag == self._drag and bool(self.edits)
            return replacing, len(self.edits) - (1 if replacing else 0)

        with self._lock:
            (replacing, k), seq0 = target(), self.seq
            base = self.design_at(k)
        d = self._apply(edit, base)  # raises before anything changes
        with self._lock:
            if out_of_time(deadline):
                raise InputError(f"edit {edit.op!r} did not finish within its time limit; nothing changed")
            if self.seq != seq0 or target() != (replacing, k):
                raise InputError(f"edit {edit.op!r}: the design changed while it was computed (an edit from "
                                 "another page); nothing changed, make it again")
            if replacing:
                self.edits[-1] = edit
                self._forget_from(k + 1)
            else:
                self.edits.append(edit)
            self._remember(k + 1, d)
            self.redo_stack.clear()
            self._drag = drag
            self.seq += 1
            return self.seq

    def end_drag(self) -> None:
        """The drag is over: the next step with the same id adds a new edit."""
        self._drag = None

    def undo(self) -> int:
        """Take back the last edit (a whole drag is one edit). Returns the new :attr:`seq`."""
        with self._lock:
            if self.edits:
                self.redo_stack.append(self.edits.pop())
                self._forget_from(len(self.edits) + 1)
                self._drag = None
                self.seq += 1
            return self.seq

    def redo(self) -> int:
        """Apply the last undone edit again."""
        with self._lock:
            if self.redo_stack:
                e = self.redo_stack.pop()
                d = self._apply(e, self.design)
                self.edits.append(e)
                self._remember(len(self.edits), d)
                self._drag = None
                self.seq += 1
            return self.seq

    # -- the edit script ----------------------------------------------------------------
    def script(self) -> EditScript:
        """The log as an edit script (``selfsupport edit`` replays it, a solve after each edit)."""
        s = self.start
        start_obj = [] if s.objective is None else [_objective_edit(s.objective)]
        edits = tuple(start_obj + list(self.edits))
        return EditScript(edits=edits, solve_after=(True,) * len(edits), scene=self.scene_spec,
                          density=s.density, thickness=s.thickness, w_max=s.w_max, solve=dict(self.solve))

    @classmethod
    def from_script(cls, script: EditScript, start: Design, *, scene_spec: str | None = None) -> "EditLog":
        """A log holding the edits of ``script`` (applied, not solved) on ``start``."""
        log = cls(start, scene_spec=scene_spec if scene_spec is not None else script.scene, solve=script.solve)
        for e in script.edits:
            log.apply(e)
        return log

    # -- internals ------------------------------------------------------------------------
    @staticmethod
    def _apply(edit: Edit, design: Design) -> Design:
        # each design is a stage of its own: origins refer to the design before the edit
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused below, in one message
            d = edit.apply(replace(design, origin=None))
        sc = d.scene
        for name, a in (("vertex positions", sc.mesh.vertices), ("extra masses", sc.extra_mass),
                        ("point loads", sc.point_loads)):
            if a is not None and not np.isfinite(a).all():  # e.g. an offset of 1e308 times the diagonal
                raise InputError(f"edit {edit.op!r} would make the {name} infinite or NaN; give smaller values")
        return d

    def _remember(self, k: int, d: Design) -> None:
        self._designs[k] = d
        n = len(self.edits)
        for j in [j for j in self._designs if j and j % _CHECKPOINT_EVERY and j < n - _KEEP_RECENT]:
            del self._designs[j]

    def _forget_from(self, k: int) -> None:
        for j in [j for j in self._designs if j >= k]:
            del self._designs[j]


def _objective_edit(weights: Mapping[str, float]) -> Edit:

    return Objective(weights=dict(weights))


# ----------------------------------------------------------------------------- the worker
@dataclass(frozen=True)
class _Job:
    seq: int
    design: Design
    kind: str = "solve"  # or "probe"
    args: Mapping[str, Any] | None = None
    t0: float | None = None  # when the change was received (perf_counter), for the frame's latency


class SolveWorker:
    """Solves designs in one background thread, newest first, warm-started (module docstring).

    Parameters
    ----------
    emit
        Called from the worker thread with every message: ``{"type": "frame", ...}`` (a solved
        network, :func:`frame_payload`), ``"analysis"`` (Airy surface, reciprocal diagram, from a
        thread of its own), ``"progress"`` (iteration count), ``"error"``, ``"probe"`` (stability probe).
    options
        Options of the staggered method (:data:`SOLVE_DEFAULTS` first).
    analysis
        Compute the analysis panels after each frame (skipped while a newer request waits).
    analysis_delay
        Seconds a frame's analysis waits for the edits to pause; a newer edit in that time drops
        it. While a drag goes on, the analysis would share the CPUs with the next edit's solve
        and delay its frame, and the page draws the panels only when the edits pause anyway.
    max_stale
        Seconds without a frame after which a newer request no longer cancels the running
        solve: it finishes, its (one edit old) frame goes out, then the newest request is
        solved, warm from the last frame that came out in turn. On a machine 2.7x slower than
        the one the tool was written on, a drag step's solve of a 300-vertex vault outlasted the
        drag's steps (0.3 s apart), every solve was cancelled, and the page showed nothing until
        the drag ended.
    """

    def __init__(self, emit: Callable[[dict], None], *, options: Mapping[str, Any] | None = None,
                 analysis: bool = True, analysis_delay: float = 0.15, max_stale: float = 1.0) -> None:

        opts = {**SOLVE_DEFAULTS, **dict(options or {})}
        self.warm = bool(opts.pop("warm", True))
        self.method = StaggeredLinearization(backend=opts.pop("backend", "active-set"))
        self.options = opts
        self.emit = emit
        self.analysis = analysis
        self.analysis_delay = float(analysis_delay)
        self.max_stale = float(max_stale)
        # when frames were last fresh: the last frame, or the start of a solve that no cancelled
        # solve preceded (after a pause the stale clock starts with the drag, not the last frame)
        self._frame_at = time.perf_counter()
        self._after_cancel = False  # the last solve was cancelled (the clock runs on)
        self.last = None  # the last network found (the next warm start)
        self.last_seq = -1
        self._pending: _Job | None = None
        self._submitted = -1  # the newest seq submitted
        self._probe: _Job | None = None
        self._cv = threading.Condition()
        self._closed = False
        # the analysis panels have their own thread: the next edit's solve does not wait for them
        self._analysis_job: tuple | None = None
        self._acv = threading.Condition()
        self._thread = threading.Thread(target=self._run, name="selfsupport-solver", daemon=True)
        self._thread.start()
        self._athread = threading.Thread(target=self._run_analysis, name="selfsupport-analysis", daemon=True)
        self._athread.start()

    def submit(self, seq: int, design: Design, *, t0: float | None = None) -> None:
        """Solve ``design`` (change number ``seq``) next; an older request still waiting is dropped
        and a running one stops at its next iteration. ``t0``: when the change was received
        (``time.perf_counter()``; default now), the start of the frame's ``latency_s``."""
        with self._cv:
            if seq < self._submitted:  # two pages' edits raced: an older design never replaces a newer one
                return
            self._submitted = seq
            self._pending = _Job(seq, design, t0=time.perf_counter() if t0 is None else t0)
            self._cv.notify_all()

    def probe(self, seq: int, design: Design, vertex: int, **kw: Any) -> None:
        """The largest extra mass at ``vertex`` that still admits a network inside the hull
        (:func:`selfsupport.structure.stability.max_load`), after the pending solve."""
        with self._cv:
            self._probe = _Job(seq, design, "probe", {"vertex": int(vertex), **kw})
            self._cv.notify_all()

    def close(self, timeout: float = 30.0) -> None:
        """Stop the thread (a running solve stops at its next iteration)."""
        with self._cv:
            self._closed = True
            self._cv.notify_all()
        with self._acv:
            self._acv.notify_all()
        self._thread.join(timeout)
        self._athread.join(timeout)

    # -- thread ---------------------------------------------------------------------------
    def _newer(self, seq: int) -> bool:
        p = self._pending
        return p is not None and p.seq > seq

    def _cancel(self, seq: int) -> bool:
        """Stop the running solve of ``seq``: closed, or a newer request waits while frames are
        still going out (within ``max_stale`` of the last one, or of the start of the first solve
        after a pause)."""
        return self._closed or (self._newer(seq) and time.perf_counter() - self._frame_at < self.max_stale)

    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._closed and self._pending is None and self._probe is None:
                    self._cv.wait()
                if self._closed:
                    return
                if self._pending is not None:
                    job, self._pending = self._pending, None
                else:
                    job, self._probe = self._probe, None
            cancelled = False
            try:
                if job.kind == "solve":
                    if not self._after_cancel:
                        self._frame_at = time.perf_counter()
                    self._solve(job)
                else:
                    self._run_probe(job)
            except Superseded:
                cancelled = True
                self.emit({"type": "cancelled", "seq": job.seq, "what": job.kind})
            except SelfSupportError as e:
                self.emit({"type": "error", "seq": job.seq, "what": job.kind, "message": str(e)})
            except Exception as e:  # noqa: BLE001 - a failing solve must not kill the session
                self.emit({"type": "error", "seq": job.seq, "what": job.kind,
                           "message": f"{type(e).__name__}: {e}"})
            if job.kind == "solve":
                self._after_cancel = cancelled

    def _solve(self, job: _Job) -> None:

        t0 = job.t0 if job.t0 is not None else time.perf_counter()
        design = job.design
        validate_scene(design.scene)  # unusable input: one clear message, no solve
        self.emit({"type": "solving", "seq": job.seq})

        def progress(rec: dict) -> None:
            if self._cancel(job.seq):
                raise Superseded
            self.emit({"type": "progress", "seq": job.seq, "iteration": rec.get("iteration"),
                       "error": _finite(rec.get("max_rel_error", rec.get("rel_error")))})

        ws = WarmStart(self.last.network) if (self.warm and self.last is not None) else None
        res = solve_warm(self.method, design.problem(), dict(self.options), progress=progress, warm_start=ws)
        if self._cancel(job.seq):
            raise Superseded
        # a frame out of turn (finished past max_stale, a newer request waiting) is shown only: the
        # next warm start and the saved network stay those of the last frame in turn, so a burst
        # of edits ends on the network it ended on before (test_design_server's 200 edits: the
        # cold solve's, 4e-8 apart; warm from a frame out of turn, 0.8-3.4e-3 of the diagonal)
        in_turn = not self._newer(job.seq)
        if in_turn:
            self.last, self.last_seq = res, job.seq
        frame = frame_payload(res, design, seq=job.seq)
        frame["latency_s"] = time.perf_counter() - t0
        frame["warm"] = bool((res.parameters.get("warm_start") or {}).get("used"))
        self._frame_at = time.perf_counter()
        self.emit(frame)
        if self.analysis and in_turn:
            with self._acv:
                self._analysis_job = (job.seq, res.network, design)
                self._acv.notify_all()

    def _run_analysis(self) -> None:
        while True:
            with self._acv:
                while not self._closed and self._analysis_job is None:
                    self._acv.wait()
                if self._closed:
                    return
                (seq, net, design), self._analysis_job = self._analysis_job, None
            with self._cv:  # (submit notifies it) a newer design's frame brings its own analysis
                self._cv.wait_for(lambda: self._closed or self._submitted > seq, timeout=self.analysis_delay)
                if self._closed or self._submitted > seq:
                    continue
            try:
                self.emit(analysis_payload(net, design, seq=seq))
            except Exception as e:  # noqa: BLE001 - the panels are optional; the frame is out already
                self.emit({"type": "error", "seq": seq, "what": "analysis", "message": f"{type(e).__name__}: {e}"})

    def _run_probe(self, job: _Job) -> None:

        a = dict(job.args or {})
        v = a.pop("vertex")
        d = job.design
        self.emit({"type": "probing", "seq": job.seq, "vertex": v})

        def progress(step: Any) -> None:
            self.emit({"type": "probe_step", "seq": job.seq, "vertex": v, "kg": step.kg, "found": step.certified})
            if self._pending is not None or self._closed:
                raise Superseded  # an edit came in: the probe refers to an old design

        opts = {**self.options, "time_limit": float(a.pop("time_limit", 20.0))}
        m = max_load(d.scene, thickness=d.thickness, density=d.density, at=[v], options=opts,
                     rel_tol=float(a.pop("rel_tol", 0.1)), start_kg=float(a.pop("start_kg", 1000.0)),
                     progress=progress, search="bisection")  # (a verdict per probe, cancellable between them)
        self.emit({"type": "probe", "seq": job.seq, "vertex": v, "kg": m.kg, "upper_kg": m.upper_kg,
                   "probes": len(m.probes)})


# ------------------------------------------------------------------------------ payloads
def _flat(a: np.ndarray, digits: int = 6) -> list:
    # rounded: 1 µm / 6 significant digits is far below what the page can show, and it halves
    # the message (the full-precision network goes to the files the page exports)
    a = np.asarray(a, float)
    return np.round(a, digits).ravel().tolist()


def frame_payload(result: Any, design: Design, *, seq: int) -> dict[str, Any]:
    """The page's frame of a solve: network positions, edges, forces [N], supports, loads [N],
    the reference (vertices and triangles), status, iterations and the max relative error."""

    net = result.network
    ref = design.scene.mesh
    forces = edge_forces(net)
    return {
        "type": "frame", "seq": seq, "status": result.status, "iterations": int(result.iterations),
        "max_rel_error": _finite(result.max_relative_error), "wall_time": float(result.wall_time),
        "message": getattr(result, "message", "") or "",
        "n_vertices": int(net.mesh.n_vertices), "n_edges": int(net.mesh.n_edges),
        "vertices": _flat(net.vertices), "edges": np.asarray(net.edges, int).ravel().tolist(),
        "forces": _flat(forces, 3), "active": np.asarray(net.active_edges, bool).astype(int).tolist(),
        "supports": np.flatnonzero(net.supports).tolist(), "loads": _flat(net.loads, 3),
        "reference": {"vertices": _flat(ref.vertices), "triangles": np.asarray(triangulate(ref), int).ravel().tolist()},
        "distance_mean": _finite(getattr(result, "distance_mean", None)),
        "design": design_summary(design),
    }


def design_summary(design: Design) -> dict[str, Any]:
    """Material, objective and load settings of a design (what the page's sliders show)."""
    sc = design.scene
    em = sc.extra_mass
    return {"density": design.density, "thickness": design.thickness, "w_max": design.w_max,
            "objective": dict(design.objective) if design.objective is not None else {"reference": 1.0},
            "extra_mass_total": float(np.sum(em)) if em is not None else 0.0,
            "n_supports": int(np.sum(sc.supports))}


def analysis_payload(network: Any, design: Design, *, seq: int) -> dict[str, Any]:
    """Airy surface φ [N·m] per vertex and the reciprocal diagram's segments [N] of ``network``;
    when they cannot be computed, why. (The hull band, reference ± t/2 along the normals, is drawn
    by the page from the frame's reference.)"""

    out: dict[str, Any] = {"type": "analysis", "seq": seq}
    try:
        a = airy_of(network)
        out["airy"] = {"phi": _flat(a.phi, 3)}
        out["reciprocal"] = {"segments": _flat(reciprocal_segments(network, a))}
    except (SelfSupportError, ValueError, np.linalg.LinAlgError) as e:
        out["airy_error"] = str(e)
    return out
