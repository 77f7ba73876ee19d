"""Running a sweep on dask.distributed: one task per run, results stored as they finish.

* **Cluster.** A :class:`distributed.LocalCluster` by default (worker processes, one thread
  each, as many as the machine has cores; BLAS is pinned to one thread per worker by the
  nanny), or an existing cluster given by its scheduler address (its workers need
  ``selfsupport`` installed; scene content travels with the tasks, so they do not need the
  scene files).
* **Tasks.** Each scene is loaded once on the client (its content digest keys the runs) and
  handed to the cluster as one small task that the runs depend on, so a lost copy is simply
  recomputed. Each run is one task, :func:`execute_run`: it builds the loads, calls the
  method with ``time_limit = time_budget`` and returns a flat result row. An exception is
  caught there and becomes a ``failed`` row with its message.
* **Hard backstop.** A run still going ``grace`` seconds after its budget is cancelled, its
  worker restarted (a Python thread cannot be stopped otherwise) and a ``timeout`` row
  written. A run whose worker dies (segfault, out of memory) is retried once by the
  scheduler, then written as ``crashed``.
* **Resume.** Runs whose key is already stored are skipped; each finished run is inserted
  atomically by the client as soon as its result arrives (:mod:`.store`), so a killed sweep
  re-run with the same command finishes exactly what is missing.
* **Progress** on stderr with rich: runs done / failed / running / remaining and an ETA
  (plain lines every few seconds when stderr is not a terminal).
"""
from __future__ import annotations

import json
import math
import os
import resource
import socket
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from selfsupport.api import METHODS
from selfsupport.core.errors import InputError, SelfSupportError
from selfsupport.core.loads import SelfWeight
from selfsupport.core.result import STATUSES
from selfsupport.core.scene import Scene
from selfsupport.io.network_json import finite_or_none as _finite
from selfsupport.sweep.spec import RunSpec, SweepSpec, split_options
from selfsupport.sweep.store import COLUMN_NAMES, ResultStore, run_key, scene_digest

__all__ = ["ERROR_STATUSES", "SweepOutcome", "PlannedRun", "plan_runs", "execute_run", "run_sweep",
           "default_workers", "STORE_NAME"]

#: Statuses the sweep machinery itself assigns (the methods' own are in selfsupport.core.result.STATUSES).
ERROR_STATUSES = ("failed", "timeout", "crashed")
#: File name of the store inside the output folder.
STORE_NAME = "results.sqlite"
#: Event topic on which workers announce that a run started (for the hard backstop and ETA).
START_TOPIC = "selfsupport-sweep-start"
#: Dask settings of the embedded LocalCluster. Saturation 1.0: a worker holds only the task it
#: runs, so restarting it (hard timeout) never takes an innocent queued run with it.
#: allowed-failures 1: a run that kills its worker is tried once more, then recorded as crashed.
LOCAL_CLUSTER_CONFIG = {"distributed.scheduler.worker-saturation": 1.0,
                        "distributed.scheduler.allowed-failures": 1}


def default_workers() -> int:
    """One worker process per core available to this process."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


# ---------------------------------------------------------------------------- worker side
class _PeakRss:
    """Peak resident memory [MB] of this process during a run.

    Linux resets the high-water mark on writing ``5`` to ``/proc/self/clear_refs``; elsewhere
    the process's lifetime peak (``ru_maxrss``) is reported, an upper bound.
    """

    def __init__(self) -> None:
        try:
            with open("/proc/self/clear_refs", "w") as f:
                f.write("5")
            self.exact = True
        except OSError:
            self.exact = False

    def read(self) -> float:
        if self.exact:
            try:
                with open("/proc/self/status") as f:
                    for line in f:
                        if line.startswith("VmHWM:"):
                            return int(line.split()[1]) / 1024.0
            except OSError:
                pass
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _announce(key: str) -> str:
    """Tell the client that run ``key`` starts on this worker; returns the worker address."""
    try:
        from distributed import get_worker
        w = get_worker()
    except (ImportError, ValueError):
        return ""
    w.log_event(START_TOPIC, {"key": key, "worker": w.address, "t": time.time()})
    return w.address


def _error_message(exc: BaseException) -> str:
    tb = traceback.extract_tb(exc.__traceback__)
    where = f" (at {Path(tb[-1].filename).name}:{tb[-1].lineno} in {tb[-1].name})" if tb else ""
    return f"{type(exc).__name__}: {exc}{where}"


def execute_run(scene: Scene, run: dict[str, Any]) -> dict[str, Any]:
    """Solve one run on a worker and return its result columns (never raises for a solve error).

    Parameters
    ----------
    scene
        The scene (shared by all runs on it).
    run
        ``key``, ``method``, ``backend``, ``params`` (density, thickness, w_max, eps, tol,
        max_iter, objective), ``options``, ``time_budget``.
    """

    t_task = time.perf_counter()
    started = time.time()
    worker = _announce(run["key"])
    rss = _PeakRss()
    p = run["params"]
    out: dict[str, Any] = {"worker": worker, "host": socket.gethostname(), "pid": os.getpid(),
                           "started_at": started, "n_vertices": scene.mesh.n_vertices,
                           "n_edges": int(scene.active_edges.sum())}
    t0 = time.perf_counter()
    try:
        cls = METHODS[run["method"]].load()
        ctor, solve_kw = split_options(cls, run["options"])
        if run["backend"] is not None:
            ctor["backend"] = run["backend"]
        stops = {"max_iter": p["max_iter"]} if p["max_iter"] is not None else {}
        # the methods add the scene's own extra masses / point loads to the load case themselves
        objective = p.get("objective")
        res = cls(**ctor).solve(scene, SelfWeight(density=p["density"], thickness=p["thickness"]),
                                eps=p["eps"], w_max=p["w_max"], tol=p["tol"], time_limit=run["time_budget"],
                                objective=objective.split() if objective else None, **stops, **solve_kw)
        out.update(status=res.status, backend=res.backend, iterations=int(res.iterations), message=res.message,
                   max_rel_error=_finite(res.max_relative_error), min_weight=_finite(res.min_weight),
                   distance_mean=_finite(res.distance_mean), distance_max=_finite(res.distance_max))
    except Exception as exc:  # noqa: BLE001 - a failing run is data, the sweep goes on
        out.update(status="failed", message=_error_message(exc))
    out["solve_time"] = time.perf_counter() - t0
    out["peak_rss_mb"] = rss.read()
    out["finished_at"] = time.time()
    out["task_time"] = time.perf_counter() - t_task
    return out


def _hold_scene(scene: Scene) -> Scene:
    """The task that makes a scene available on the cluster (recomputed if its copy is lost)."""
    return scene


# ---------------------------------------------------------------------------- planning
@dataclass(frozen=True)
class PlannedRun:
    """A run with its store key and the columns known before it executes."""

    key: str
    run: RunSpec
    scene_index: int
    columns: dict[str, Any]

    def payload(self) -> dict[str, Any]:
        return {"key": self.key, "method": self.run.method, "backend": self.run.backend,
                "params": self.run.param_dict, "options": self.run.option_dict,
                "time_budget": self.run.time_budget}


@dataclass(frozen=True)
class Plan:
    """All runs of a sweep, keyed, with the scenes loaded (None where loading failed)."""

    runs: tuple[PlannedRun, ...]
    scenes: tuple[Scene | None, ...]
    scene_errors: tuple[str | None, ...]
    duplicates: int

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(r.key for r in self.runs)


def plan_runs(spec: SweepSpec) -> Plan:
    """Load every scene (on the client), compute the run keys, drop duplicate keys."""
    scenes: list[Scene | None] = []
    errors: list[str | None] = []
    digests: list[str] = []
    for ref in spec.scenes:
        try:
            sc = ref.load()
            scenes.append(sc)
            errors.append(None)
            digests.append(scene_digest(sc))
        except (SelfSupportError, OSError, ValueError) as exc:
            # recorded as failed runs: a bad scene must not stop the other scenes
            scenes.append(None)
            errors.append(f"scene {ref.label!r} could not be loaded: {exc}")
            digests.append("unloadable:" + json.dumps([ref.kind, ref.label, str(ref.path), ref.shape,
                                                       list(map(list, ref.shape_params))], default=str))
    index = {ref: k for k, ref in enumerate(spec.scenes)}
    planned: list[PlannedRun] = []
    seen: set[str] = set()
    dup = 0
    for run in spec.expand():
        k = index[run.scene]
        key = run_key(digests[k], run.identity())
        if key in seen:
            dup += 1
            continue
        seen.add(key)
        p = run.param_dict
        cols = {"key": key, "sweep": spec.name, "scene": run.scene.label, "scene_digest": digests[k],
                "method": run.method, "backend": run.backend, **p,
                "options": run.option_dict, "repetition": run.repetition, "time_budget": run.time_budget,
                "params": {**p, "options": run.option_dict, "scene": run.scene.label}}
        planned.append(PlannedRun(key=key, run=run, scene_index=k, columns=cols))
    return Plan(runs=tuple(planned), scenes=tuple(scenes), scene_errors=tuple(errors), duplicates=dup)


# ---------------------------------------------------------------------------- progress
def _fmt_eta(seconds: float | None) -> str:
    if seconds is None or not math.isfinite(seconds):
        return "?"
    s = int(round(seconds))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


class _Progress:
    """done / failed / running / remaining / ETA on stderr (rich bar on a terminal, plain
    lines every ``interval`` seconds otherwise, nothing when disabled)."""

    def __init__(self, total: int, enabled: bool, interval: float = 5.0) -> None:
        from rich.console import Console

        self.total, self.enabled, self.interval = total, enabled, interval
        self.console = Console(stderr=True)
        self.t0 = time.perf_counter()
        self.last_line = 0.0
        self.done = self.failed = self.running = 0
        self.printed: tuple[int, int] = (-1, -1)
        self.bar = None
        if enabled and self.console.is_terminal:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
            self.bar = Progress(TextColumn("[bold]sweep"), BarColumn(), MofNCompleteColumn(),
                                TextColumn("{task.fields[info]}"), TimeElapsedColumn(), console=self.console)
            self.task = self.bar.add_task("runs", total=total, info="")
            self.bar.start()

    def eta(self) -> float | None:
        if self.done == 0:
            return None
        rate = self.done / (time.perf_counter() - self.t0)
        return (self.total - self.done) / rate

    def info(self) -> str:
        return (f"failed {self.failed} · running {self.running} · remaining {self.total - self.done} · "
                f"ETA {_fmt_eta(self.eta())}")

    def update(self, done: int, failed: int, running: int, force: bool = False) -> None:
        self.done, self.failed, self.running = done, failed, running
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.update(self.task, completed=done, info=self.info())
            return
        now = time.perf_counter()
        changed = (done, failed) != self.printed
        # a line when something finished (at most every `interval` s), else a heartbeat per minute
        if force or (changed and now - self.last_line >= self.interval) or now - self.last_line >= 60.0:
            self.last_line, self.printed = now, (done, failed)
            self.console.print(f"sweep: done {done}/{self.total} · {self.info()}", highlight=False)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()
        elif self.enabled:
            self.update(self.done, self.failed, self.running, force=True)


# ---------------------------------------------------------------------------- driver
@dataclass(frozen=True)
class SweepOutcome:
    """What one invocation did. ``keys`` are all the sweep's runs (for reports and exports)."""

    session: str
    store_path: Path
    keys: tuple[str, ...]
    n_runs: int
    n_skipped: int
    n_executed: int
    n_duplicates: int
    by_status: dict[str, int] = field(default_factory=dict)
    wall_time: float = 0.0
    cluster: str = ""
    interrupted: bool = False
    n_lost: int = 0  # cancelled by the cluster (not by us): not stored, run again next time

    @property
    def n_failed(self) -> int:
        return sum(self.by_status.get(s, 0) for s in ERROR_STATUSES)


class _Cluster:
    """The client to use: given, connected to ``scheduler``, or on a new LocalCluster."""

    def __init__(self, client: Any = None, scheduler: str | None = None, workers: int | None = None) -> None:
        import dask
        from distributed import Client, LocalCluster

        self.own_client = client is None
        self.cluster = None
        if client is not None:
            self.client = client
            self.description = f"client {getattr(client, 'scheduler', None) and client.scheduler.address}"
        elif scheduler:
            try:
                self.client = Client(scheduler, timeout="30s")
            except (OSError, TimeoutError) as e:
                raise InputError(f"cannot connect to the dask scheduler at {scheduler}: {e}; "
                                 "check the address (tcp://host:8786) and that the scheduler runs") from None
            self.description = f"scheduler {scheduler}"
        else:
            n = workers or default_workers()
            if n < 1:
                raise InputError(f"--workers must be at least 1, got {n}")
            with dask.config.set(LOCAL_CLUSTER_CONFIG):
                self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                            dashboard_address=None)
                self.client = Client(self.cluster)
            self.description = f"LocalCluster({n} workers x 1 thread)"

    def close(self) -> None:
        if self.own_client:
            try:
                self.client.close()
            finally:
                if self.cluster is not None:
                    self.cluster.close()


def run_sweep(spec: SweepSpec, out_dir: str | Path, *, scheduler: str | None = None, workers: int | None = None,
              client: Any = None, retry: Iterable[str] = (), progress: bool = True,
              poll: float = 0.05, on_row: Callable[[dict], None] | None = None) -> SweepOutcome:
    """Run every run of ``spec`` that is not yet in ``out_dir``'s store.

    Parameters
    ----------
    spec
        The sweep (:func:`selfsupport.sweep.spec.load_spec`).
    out_dir
        Output folder; the store is ``out_dir / STORE_NAME``.
    scheduler, workers, client
        Where to run: an existing ``distributed.Client``, else a scheduler address, else a new
        LocalCluster with ``workers`` processes (default: one per core).
    retry
        Statuses (e.g. ``("failed", "timeout")``) whose stored runs are executed again and
        their rows replaced.
    progress
        Show progress on stderr.
    poll
        Seconds between checks of the running tasks.
    on_row
        Called with each stored row (after it is committed).

    Returns
    -------
    SweepOutcome
        Counts for this invocation; a Ctrl-C returns with ``interrupted=True`` after the
        cluster is shut down (every finished run is stored).
    """
    t_start = time.perf_counter()
    retry = set(retry)
    bad = retry - set(ERROR_STATUSES) - _method_statuses()
    if bad:
        raise InputError(f"cannot retry unknown status(es) {sorted(bad)}; "
                         f"statuses are {', '.join(ERROR_STATUSES + tuple(sorted(_method_statuses())))}")
    out_dir = Path(out_dir)
    plan = plan_runs(spec)
    store = ResultStore(out_dir / STORE_NAME)
    try:
        stored = store.statuses()
        todo = [r for r in plan.runs if r.key not in stored or stored[r.key] in retry]
        replace = {r.key for r in todo if r.key in stored}
        by_status: dict[str, int] = {}
        executed = 0

        def record(pr: PlannedRun, result: dict[str, Any]) -> str:
            nonlocal executed
            row = {**pr.columns, **result, "session": session}
            row = {k: v for k, v in row.items() if k in COLUMN_NAMES}
            if store.insert(row, replace=pr.key in replace):
                executed += 1
                by_status[row["status"]] = by_status.get(row["status"], 0) + 1
                if on_row:
                    on_row(row)
            return row["status"]

        # runs of scenes that could not be loaded need no cluster
        unloadable = [r for r in todo if plan.scenes[r.scene_index] is None]
        todo = [r for r in todo if plan.scenes[r.scene_index] is not None]
        cluster = _Cluster(client, scheduler, workers) if todo else None
        session = store.begin_session(sweep=spec.name, spec_sha256=spec.digest, spec=spec.text,
                                      n_runs=len(plan.runs), n_todo=len(todo) + len(unloadable),
                                      cluster=cluster.description if cluster else "")
        n_skipped = len(plan.runs) - len(todo) - len(unloadable)
        if progress:  # (the counts of the summary table: runs, already stored, executed now)
            from rich.console import Console

            bad = f" ({len(unloadable)} of them of a scene that cannot be loaded: recorded as failed)" if unloadable else ""
            Console(stderr=True, soft_wrap=True).print(
                f"sweep: {len(plan.runs)} runs, {n_skipped} already stored, {len(todo) + len(unloadable)} to do now{bad}",
                highlight=False)
        now = time.time()
        for pr in unloadable:
            record(pr, {"status": "failed", "message": plan.scene_errors[pr.scene_index],
                        "started_at": now, "finished_at": now})
        interrupted = False
        lost = 0
        if cluster is not None:
            try:
                lost = _execute(cluster, spec, plan, todo, store, session, record, progress, poll)
            except KeyboardInterrupt:
                interrupted = True
            finally:
                cluster.close()
        return SweepOutcome(session=session, store_path=store.path, keys=plan.keys, n_runs=len(plan.runs),
                            n_skipped=n_skipped, n_executed=executed,
                            n_duplicates=plan.duplicates, by_status=by_status,
                            wall_time=time.perf_counter() - t_start,
                            cluster=cluster.description if cluster else "", interrupted=interrupted,
                            n_lost=lost)
    finally:
        store.close()


def _method_statuses() -> set[str]:
    return set(STATUSES)


def _execute(cluster: _Cluster, spec: SweepSpec, plan: Plan, todo: list[PlannedRun], store: ResultStore,
             session: str, record: Callable[[PlannedRun, dict], str], show: bool, poll: float) -> int:
    """Submit ``todo``, record results as they come, enforce the hard limit; returns the
    number of runs lost to cancellations we did not ask for (left to do)."""
    from distributed import as_completed

    client = cluster.client
    started: dict[str, tuple[float, str]] = {}  # run key -> (start time, worker)
    lock = threading.Lock()

    def on_start(event: Any) -> None:
        _, msg = event
        with lock:  # the client's clock: the backstop must not depend on remote clocks agreeing
            started[msg["key"]] = (time.time(), msg["worker"])

    client.subscribe_topic(START_TOPIC, on_start)
    progress = _Progress(total=len(todo), enabled=show)
    futures: dict[Any, PlannedRun] = {}
    try:
        scene_futs = {}
        for k in sorted({r.scene_index for r in todo}):
            scene_futs[k] = client.submit(_hold_scene, plan.scenes[k], key=f"scene-{session}-{k}", pure=False)
        store.log_attempts(session, [r.key for r in todo])
        for pr in todo:
            # the session in the task key: a cluster that still holds an earlier session's result
            # under the same name must not hand it back instead of running again (retry)
            fut = client.submit(execute_run, scene_futs[pr.scene_index], pr.payload(),
                                key=f"run-{pr.key}-{session}", pure=False)
            futures[fut] = pr
        by_key = {pr.key: fut for fut, pr in futures.items()}
        ac = as_completed(list(futures))
        done = failed = lost = 0
        finished: set[str] = set()
        while len(finished) < len(futures):
            for fut in ac.next_batch(block=False) if ac.has_ready() else ():
                pr = futures[fut]
                if pr.key in finished:
                    continue  # cancelled by the backstop, already recorded as timeout
                result = _collect(fut, pr, started)
                status = record(pr, result) if result is not None else "lost"
                lost += result is None
                finished.add(pr.key)
                done += 1
                failed += status in ERROR_STATUSES
            # hard backstop: give up on runs far beyond their budget
            now = time.time()
            with lock:
                late = [(k, t, w) for k, (t, w) in started.items()
                        if k not in finished and now - t > spec.hard_limit]
            for k, t, w in late:
                fut = by_key.get(k)
                if fut is None or fut.done():
                    continue  # its result arrived meanwhile: the next batch records it
                fut.cancel()
                record(futures[fut], {"status": "timeout", "worker": w, "started_at": t, "finished_at": now,
                                      "message": f"no result {spec.hard_limit:g} s after the start (budget "
                                                 f"{spec.time_budget:g} s + grace {spec.grace:g} s); "
                                                 "run cancelled, worker restarted"})
                finished.add(k)
                done += 1
                failed += 1
                try:  # the only way to stop a running Python task is to stop its process
                    client.restart_workers([w], raise_for_error=False)
                except Exception:  # noqa: BLE001 - a worker without a nanny cannot restart
                    pass
            with lock:
                running = sum(1 for k in started if k not in finished)
            progress.update(done, failed, running)
            if len(finished) < len(futures) and not ac.has_ready():
                time.sleep(poll)
        return lost
    finally:
        progress.close()
        try:
            client.unsubscribe_topic(START_TOPIC)
        except Exception:  # noqa: BLE001
            pass
        live = [f for f in futures if not f.done()]
        if live:
            client.cancel(live)


def _collect(fut: Any, pr: PlannedRun, started: dict[str, tuple[float, str]]) -> dict[str, Any] | None:
    """The result row of a finished future. :func:`execute_run` catches the solve's own errors,
    so what is left is the cluster's: a worker that died under the run (``crashed``), a task
    that could not run there (``failed``, e.g. selfsupport missing on a remote worker), or a
    cancellation we did not ask for (None: not a result, the run stays to do)."""
    from distributed import KilledWorker

    if fut.status == "finished":
        return fut.result()
    t, w = started.get(pr.key, (time.time(), ""))
    try:
        exc = fut.exception()
    except Exception as e:  # noqa: BLE001 - cancelled futures raise here
        exc = e
    if fut.status == "cancelled" or type(exc).__name__ == "CancelledError":
        return None
    status = "crashed" if isinstance(exc, KilledWorker) else "failed"
    return {"status": status, "worker": w, "started_at": t, "finished_at": time.time(),
            "message": f"{type(exc).__name__}: {exc}"}
