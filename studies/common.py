"""Shared pieces of the studies: the paper's Table 1, scene lookup, isolated timed runs,
peak memory, an independent equilibrium check of saved networks and a CSV/Markdown writer.

Nothing here imports the solver at module level: a study's parent process stays light and
every measured solve runs in its own freshly spawned interpreter (:func:`run_isolated`), so
that a crash, a hang or a memory blow-up costs one row, not the table, and peak memory is
measured per row.
"""
from __future__ import annotations

import csv
import importlib
import io
import json
import math
import multiprocessing as mp
import os
import platform
import resource
import subprocess
import sys
import time
import traceback
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

#: the project's checkout, and the independent checker beside it (``../shared/tools``)
REPO = Path(__file__).resolve().parent.parent
DEFAULT_CHECKER = REPO.parent / "shared" / "tools" / "check_network.py"

# ------------------------------------------------------------------------------ the paper
@dataclass(frozen=True)
class PaperScene:
    """One input of the paper's Table 1 and what the paper reports for it.

    Attributes
    ----------
    name
        File stem in the scenes folder (``lilium`` for ``lilium.sss``).
    file
        File name in the scenes folder.
    figure
        Figure of the paper showing the result.
    vertices, edges
        Mesh size as printed in Table 1 (cyl2: the table says 2358 vertices, the file has 2348).
    time_s, iterations, max_rel_error
        The paper's solve time (Xeon 2.3 GHz), outer iterations and max relative error.
    up
        The file's vertical axis (``None``: the format's convention).
    supports
        Supports file in the scenes folder (``None``: the file's own pins).
    published
        The paper's resulting network in the published folder, in the same vertex order
        (``None``: none, or not in the same order).
    """

    name: str
    file: str
    figure: str
    vertices: int
    edges: int
    time_s: float
    iterations: int
    max_rel_error: float
    up: str | None = None
    supports: str | None = None
    published: str | None = None


#: Table 1 of the paper (docs/guide/paper.md and the paper-scenes README), keyed by file stem.
PAPER_TABLE1: dict[str, PaperScene] = {s.name: s for s in (
    PaperScene("lilium", "lilium.sss", "Fig. 5b", 1201, 3504, 21.6, 9, 4.2e-5, published="lilium-n.obj"),
    PaperScene("lilium-pillar", "lilium-pillar.sss", "Fig. 5d", 1200, 3500, 26.5, 10, 8.5e-5,
               published="lilium-pillar-n.obj"),
    PaperScene("cas", "cas.sss", "Fig. 6", 1535, 2976, 17.0, 21, 2.7e-5),
    # remove-original is not twocirc-3's vertex order: no published comparison
    PaperScene("twocirc-3", "twocirc-3.sss", "Fig. 8", 752, 2165, 8.0, 9, 5.8e-5),
    PaperScene("cyl2", "cyl2.sss", "Fig. 11", 2358, 4302, 19.5, 9, 3.0e-4, published="cheese-n.obj"),
    PaperScene("structural", "structural.obj", "Fig. 16", 527, 998, 5.7, 25, 2.4e-5, up="-y",
               supports="structural.supports", published="structural-n.obj"),
)}

#: Vertical axis of the published OBJ networks (the paper's convention: height = −y).
PUBLISHED_UP = "-y"


#: Suffixes of the scene files a study finds in a folder by itself (a JSON file there may be a
#: network written by a run, so JSON scenes are named with ``--only``).
SCENE_SUFFIXES = (".sss", ".obj", ".ply", ".off")


def study_scenes(scenes_dir: Path, only: Sequence[str] | None = None) -> list[str]:
    """The scenes a study runs, by name (file stem): ``only`` when given; else the Table 1
    scenes found in ``scenes_dir``, in the paper's order; else every scene file there (sorted),
    so that a folder of other scenes of the same kind runs as it is, without ``--only``.

    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp())
    >>> for f in ("b.obj", "b.supports", "a.sss", "notes.txt"):
    ...     _ = (d / f).write_text("")
    >>> study_scenes(d), study_scenes(d, ["b"])
    (['a', 'b'], ['b'])
    >>> _ = (d / "cas.sss").write_text("")
    >>> study_scenes(d)
    ['cas']
    """
    if only:
        return list(only)
    table1 = [s for s in PAPER_TABLE1 if (Path(scenes_dir) / PAPER_TABLE1[s].file).is_file()]
    if table1:
        return table1
    return sorted({p.stem for p in Path(scenes_dir).iterdir() if p.is_file() and p.suffix in SCENE_SUFFIXES})


def study_scenes_or_exit(scenes_dir: Path, only: Sequence[str] | None = None) -> list[str]:
    """:func:`study_scenes` for a study's command line: a missing folder, or one with no scene
    file, ends the study with one line (``SystemExit``) instead of a traceback or an empty table."""
    if not Path(scenes_dir).is_dir():
        raise SystemExit(f"no scenes folder {scenes_dir}")
    names = study_scenes(scenes_dir, only)
    if not names:
        raise SystemExit(f"no scene file in {scenes_dir} (looked for {', '.join('*' + x for x in SCENE_SUFFIXES)})")
    return names


def scene_file(scenes_dir: Path, name: str) -> Path:
    """The scene file of ``name``: the registry's file, else ``NAME.sss`` / ``NAME.obj`` / ...."""
    spec = PAPER_TABLE1.get(name)
    candidates = [spec.file] if spec else [f"{name}{ext}" for ext in (*SCENE_SUFFIXES, ".json")]
    for c in candidates:
        p = Path(scenes_dir) / c
        if p.is_file():
            return p
    raise FileNotFoundError(f"no scene file for {name!r} in {scenes_dir} (looked for {', '.join(candidates)})")


def scene_read_args(scenes_dir: str | Path, name: str) -> tuple[Path, str | None, str | None]:
    """``(file, up, supports)`` of scene ``name``: the axis and supports file the registry gives;
    a scene not in the registry takes ``NAME.supports`` beside it when there is one (the
    convention of the paper's ``structural.obj``). ``None``: the file's own."""
    spec = PAPER_TABLE1.get(name)
    path = scene_file(Path(scenes_dir), name)
    beside = Path(scenes_dir) / f"{name}.supports"
    supports = (str(Path(scenes_dir) / spec.supports) if spec and spec.supports
                else str(beside) if spec is None and beside.is_file() else None)
    return path, spec.up if spec else None, supports


def read_study_scene(scenes_dir: str | Path, name: str):
    """Read scene ``name`` as :func:`scene_read_args` says (imports the project)."""
    from selfsupport.io import read_scene

    path, up, supports = scene_read_args(scenes_dir, name)
    return read_scene(path, up=up, supports=supports, name=name)


# ------------------------------------------------------------------------- measurements
def peak_rss_mib() -> float:
    """Peak resident set size of this process so far [MiB]: ``VmHWM`` of ``/proc/self/status``
    where there is one, else ``getrusage`` (KiB on Linux, bytes on macOS).

    Not ``getrusage`` on Linux: a spawned row process inherits there, through fork and exec, its
    parent's RSS at the fork as its ``ru_maxrss`` (a 1k row measured after a 64k one reported the
    study process's 619 MiB); ``VmHWM`` belongs to the process's own address space."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return r / (1024.0 * 1024.0) if sys.platform == "darwin" else r / 1024.0


def current_rss_mib() -> float:
    """Current resident set size [MiB] (``/proc/self/statm``; the peak where that is missing)."""
    try:
        pages = int(Path("/proc/self/statm").read_text().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 2.0 ** 20
    except (OSError, ValueError, IndexError):
        return peak_rss_mib()


class Stopwatch:
    """``with Stopwatch() as sw: ...`` then ``sw.seconds`` (wall clock, ``perf_counter``)."""

    def __enter__(self) -> "Stopwatch":
        self.seconds = float("nan")
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.seconds = time.perf_counter() - self._t0


def median_time(fn: Callable[[], Any], *, repeat: int = 5, budget: float = 10.0) -> float:
    """Median wall time of ``fn()`` over up to ``repeat`` calls (fewer if they exceed ``budget`` s)."""
    times: list[float] = []
    t_all = time.perf_counter()
    for _ in range(max(1, repeat)):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
        if time.perf_counter() - t_all > budget:
            break
    return float(np.median(times))


def load_average() -> str:
    """The 1/5/15-minute load averages, for the table header (shared machine: timings are noisy)."""
    try:
        return " / ".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:  # pragma: no cover - not on every platform
        return "n/a"


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``; else what :mod:`platform` knows)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


#: Paths (from the repository's root) that ``make bench`` itself writes.
BENCH_OUTPUTS = ("benchmarks/results", "docs/benchmarks.md")


def git_commit(repo: str | Path = REPO) -> str:
    """The short commit of ``repo``'s checkout, ``+dirty`` when it has uncommitted changes
    (``unknown`` outside git). The benchmark outputs (:data:`BENCH_OUTPUTS`) do not count: ``make
    bench`` writes them study by study, and the next study measures the same code."""
    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True,
                              timeout=30, check=True).stdout.strip()
    try:
        commit = git("rev-parse", "--short", "HEAD")
        changed = git("status", "--porcelain", "--untracked-files=no", "--", ".",
                      *(f":(exclude){p}" for p in BENCH_OUTPUTS))
        return commit + ("+dirty" if changed else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def run_stamp() -> dict[str, Any]:
    """What every row of a timing table carries, taken once at the start of a run: ``commit``,
    ``date`` (UTC, ISO 8601), ``cpu_model``, ``cores`` and ``load_start`` (the 1/5/15-minute
    load averages: the machine is shared)."""
    return {"commit": git_commit(), "date": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "cpu_model": cpu_model(), "cores": os.cpu_count() or 1, "load_start": load_average()}


# --------------------------------------------------------------------- isolated runs
def _child(target: str, kwargs: dict[str, Any], conn) -> None:
    """Run ``module:function(**kwargs)`` and send back its dict (plus peak RSS) or the error."""
    try:
        mod, fn = target.split(":")
        out = dict(getattr(importlib.import_module(mod), fn)(**kwargs))
        out.setdefault("peak_rss_mib", peak_rss_mib())
        conn.send(out)
    except BaseException as exc:  # the row records it; the table goes on
        conn.send({"status": "error", "message": f"{type(exc).__name__}: {exc}",
                   "traceback": traceback.format_exc(limit=8), "peak_rss_mib": peak_rss_mib()})
    finally:
        conn.close()


def _rss_of(pid: int) -> float:
    """Current RSS of process ``pid`` [MiB] from ``/proc`` (NaN where unavailable)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return float("nan")


#: Default memory guard of :func:`run_isolated` [MiB]: 3× the project's 2 GiB target. The
#: machine is shared; a solver whose fill-in explodes must not take the others' memory.
MAX_RSS_MIB = 6144.0


def run_isolated(target: str, kwargs: Mapping[str, Any], *, hard_timeout: float,
                 max_rss_mib: float | None = MAX_RSS_MIB, poll: float = 0.25) -> dict[str, Any]:
    """Call ``module:function(**kwargs)`` in a freshly spawned Python process.

    Spawned (not forked), so that the child's peak RSS is its own and a segfault in a native
    solver only loses this row. The child is terminated after ``hard_timeout`` seconds — a
    backstop behind the solvers' own time limits — or as soon as its resident memory exceeds
    ``max_rss_mib``; the row then has status ``"killed"`` and, for memory, the RSS seen.
    """
    ctx = mp.get_context("spawn")
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child, args=(target, dict(kwargs), send), daemon=True)
    t0 = time.perf_counter()
    proc.start()
    send.close()
    out: dict[str, Any] | None = None
    reason = f"no answer within the hard limit of {hard_timeout:g} s"
    seen_rss = 0.0
    died = False
    try:
        while time.perf_counter() - t0 < hard_timeout:
            if recv.poll(poll):
                out = recv.recv()
                break
            rss = _rss_of(proc.pid)
            seen_rss = max(seen_rss, rss) if rss == rss else seen_rss
            if max_rss_mib is not None and rss > max_rss_mib:
                reason = f"resident memory {rss:.0f} MiB exceeded the guard of {max_rss_mib:.0f} MiB"
                break
            if not proc.is_alive() and not recv.poll(0):
                died = True
                break
    except EOFError:  # the child died without a word (segfault, OOM kill)
        out, died = None, True
    except BaseException:  # interrupted (Ctrl-C, SIGTERM via exit_on_sigterm): take the child along
        proc.terminate()
        proc.join(10)
        raise
    finally:
        recv.close()
    if out is None:
        if died:
            proc.join(10)
        alive = proc.is_alive()
        if alive:
            proc.terminate()  # this one child, by its handle
        proc.join(10)
        if proc.is_alive():  # pragma: no cover - terminate ignored
            proc.kill()
            proc.join()
        if alive:
            out = {"status": "killed", "message": f"{reason}; process terminated"}
            if seen_rss:
                out["peak_rss_mib"] = seen_rss
        else:
            out = {"status": "crashed", "message": f"solver process died with exit code {proc.exitcode}"}
    else:
        proc.join(30)
    out["process_seconds"] = time.perf_counter() - t0
    return out


def exit_on_sigterm() -> None:
    """Turn SIGTERM into ``SystemExit`` so that :func:`run_isolated` stops its running child too."""
    import signal

    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))


# ------------------------------------------------------------- independent evidence
def json_network_arrays(path: str | Path) -> dict[str, np.ndarray]:
    """Vertices, edges, weights, loads and a supports mask from a network JSON (docs/reference/formats.md)."""
    d = json.loads(Path(path).read_text(encoding="utf-8"))
    V = np.asarray(d["vertices"], float)
    sup = np.zeros(len(V), bool)
    sup[np.asarray(d.get("supports", []), int)] = True
    return {"vertices": V, "edges": np.asarray(d["edges"], int).reshape(-1, 2),
            "weights": np.asarray(d["weights"], float), "loads": np.asarray(d["loads"], float), "supports": sup}


def equilibrium_errors(vertices: np.ndarray, edges: np.ndarray, weights: np.ndarray, loads: np.ndarray,
                       supports: np.ndarray) -> np.ndarray:
    """Per non-support vertex ``‖(0,0,L_i) − Σ_j w_ij (v_j − v_i)‖ / |L_i|`` (the paper's Table 1 metric).

    Written again here in plain numpy, deliberately not the project's
    :mod:`selfsupport.core.evidence`, so that the table's error column is an independent check.
    """
    r = np.zeros_like(vertices)
    f = weights[:, None] * (vertices[edges[:, 1]] - vertices[edges[:, 0]])
    np.add.at(r, edges[:, 0], f)
    np.add.at(r, edges[:, 1], -f)
    r[:, 2] -= loads
    free = ~supports
    return np.linalg.norm(r[free], axis=1) / np.maximum(np.abs(loads[free]), 1e-300)


def json_max_relative_error(path: str | Path) -> float:
    """Max relative equilibrium error of a saved network, recomputed from the JSON alone."""
    a = json_network_arrays(path)
    rel = equilibrium_errors(**a)
    return float(rel.max()) if rel.size else 0.0


def run_checker(checker: str | Path | None, network_json: str | Path) -> float:
    """``max_rel_error`` printed by the shared independent checker (``check_network.py``), or NaN.

    The checker prints ``key=value`` pairs (``vertices= … max_rel_error= …``); its exit status 1
    only means "above its tolerance", which the table reports anyway.
    """
    if checker is None or not Path(checker).is_file():
        return float("nan")
    try:
        p = subprocess.run([sys.executable, str(checker), str(network_json), "--tol", "1e300"],
                           capture_output=True, text=True, timeout=300)
    except (OSError, subprocess.SubprocessError):
        return float("nan")
    for tok in p.stdout.split():
        key, _, value = tok.partition("=")
        if key == "max_rel_error":
            try:
                return float(value)
            except ValueError:
                break
    return float("nan")


# ------------------------------------------------------------------------ table output
@dataclass(frozen=True)
class Column:
    """A table column: key in the row dicts, Markdown header and how to print a value."""

    key: str
    header: str
    fmt: str = "{}"  # format for numbers in Markdown (CSV keeps full precision)

    def text(self, value: Any) -> str:
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return ""
        if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool):
            try:
                return self.fmt.format(value)
            except (ValueError, TypeError):
                return str(value)
        return str(value).replace("|", "\\|").replace("\n", " ")


#: The columns of :func:`run_stamp`, which every study's CSV ends with.
STAMP_COLUMNS: tuple[Column, ...] = (Column("commit", "commit"), Column("date", "date"), Column("cpu_model", "CPU"),
                                     Column("cores", "cores"), Column("load_start", "load at start (1/5/15 min)"))


def write_csv(path: str | Path, rows: Sequence[Mapping[str, Any]], columns: Sequence[Column]) -> None:
    """Rows as CSV with the column keys as header (numbers unformatted, NaN as empty)."""
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow([c.key for c in columns])
    for r in rows:
        w.writerow(["" if _is_missing(r.get(c.key)) else r.get(c.key) for c in columns])
    Path(path).write_text(buf.getvalue(), encoding="utf-8")


def markdown_table(rows: Sequence[Mapping[str, Any]], columns: Sequence[Column]) -> str:
    """A GitHub-flavoured Markdown table."""
    out = ["| " + " | ".join(c.header for c in columns) + " |", "|" + "---|" * len(columns)]
    out += ["| " + " | ".join(c.text(r.get(c.key)) for c in columns) + " |" for r in rows]
    return "\n".join(out)


def write_markdown(path: str | Path, title: str, notes: Iterable[str],
                   tables: Sequence[tuple[str, Sequence[Mapping[str, Any]], Sequence[Column]]]) -> str:
    """Write ``# title``, notes as a bullet list, then each ``(subtitle, rows, columns)`` table."""
    parts = [f"# {title}", ""]
    parts += [f"* {n}" for n in notes]
    for sub, rows, cols in tables:
        parts += ["", f"## {sub}" if sub else "", "", markdown_table(rows, cols)]
    text = "\n".join(p for p in parts) + "\n"
    Path(path).write_text(text, encoding="utf-8")
    return text


def read_csv_rows(path: str | Path) -> list[dict[str, str]]:
    """The rows of a CSV written by :func:`write_csv` (values as strings)."""
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def _is_missing(v: Any) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def safe_ratio(a: Any, b: Any) -> float:
    """``a / b`` for positive finite numbers, else NaN."""
    try:
        a, b = float(a), float(b)
    except (TypeError, ValueError):
        return float("nan")
    return a / b if math.isfinite(a) and math.isfinite(b) and b > 0 else float("nan")


def vault_pillar_layout(n: int) -> tuple[np.ndarray, list[list[int]]]:
    """The paper's vault-pillar layout on an n × n grid of vertices (row-major): supports on three
    vertices at each corner and a 2 × 2 pillar in the middle, and the grid's quads. At n = 10, 168
    edges for 84 free vertices: as many edges as horizontal equations."""
    sup = np.zeros(n * n, bool)
    for i, j in ((0, 0), (0, n - 1), (n - 1, 0), (n - 1, n - 1)):
        di, dj = (1 if i == 0 else -1), (1 if j == 0 else -1)
        sup[[j * n + i, j * n + i + di, (j + dj) * n + i]] = True
    c = n // 2
    sup[[(c - 1) * n + c - 1, (c - 1) * n + c, c * n + c - 1, c * n + c]] = True
    quads = [[j * n + i, j * n + i + 1, (j + 1) * n + i + 1, (j + 1) * n + i] for j in range(n - 1) for i in range(n - 1)]
    return sup, quads
