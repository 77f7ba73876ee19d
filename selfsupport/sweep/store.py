"""The embedded result store of a sweep: one SQLite row per finished run.

* **Keyed by content.** A run's key is the SHA-256 of the scene's content (geometry, faces,
  supports, extra loads: :func:`scene_digest`) and of everything that determines its result
  (method, backend, parameters, options, repetition: :func:`run_key`). Renaming a file, or
  listing it from another folder, keeps the key; editing its geometry changes it.
* **Atomic per run.** Each row is inserted in its own committed transaction (WAL journal,
  ``synchronous=FULL``), so killing the writer at any point leaves every finished run stored
  and no partial row. A key is inserted at most once (``ON CONFLICT DO NOTHING``) unless the
  caller asks to replace it (re-running failed runs).
* **Audit trail.** ``sessions`` records each invocation; ``attempts`` records every run a
  session submitted, so one can prove that a resumed sweep did not execute a finished run
  again.

Exports: :meth:`ResultStore.export_csv`, :meth:`ResultStore.export_parquet` (atomic writes);
:func:`read_export` reads either back with the store's column types.
"""
from __future__ import annotations

import hashlib
import io
import json
import math
import sqlite3
import time
import uuid
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from selfsupport.core.errors import InputError
from selfsupport.core.scene import Scene
from selfsupport.io.atomic import atomic_write_bytes, atomic_write_text

__all__ = ["COLUMNS", "COLUMN_NAMES", "ResultStore", "scene_digest", "run_key", "read_export"]

#: Result columns: name -> (SQLite type, meaning). Times are Unix seconds (UTC), durations seconds.
COLUMNS: dict[str, tuple[str, str]] = {
    "key": ("TEXT", "sha256 of scene content + run identity"),
    "sweep": ("TEXT", "sweep name"),
    "session": ("TEXT", "id of the invocation that produced the row"),
    "scene": ("TEXT", "scene label"),
    "scene_digest": ("TEXT", "sha256 of the scene content"),
    "method": ("TEXT", "solve method"),
    "backend": ("TEXT", "method backend"),
    "density": ("REAL", "kg/m^3"),
    "thickness": ("REAL", "m"),
    "w_max": ("REAL", "N/m, NULL = unbounded"),
    "eps": ("REAL", "N/m, NULL = the method's default"),
    "tol": ("REAL", "required max relative error"),
    "max_iter": ("INTEGER", "NULL = the method's default"),
    "options": ("TEXT", "method options, JSON"),
    "repetition": ("INTEGER", "0-based"),
    "time_budget": ("REAL", "s, given to the method"),
    "status": ("TEXT", "method status, or failed / timeout / crashed"),
    "iterations": ("INTEGER", "outer iterations"),
    "solve_time": ("REAL", "s, the method's solve() call"),
    "task_time": ("REAL", "s, the whole task on the worker"),
    "max_rel_error": ("REAL", "paper's Table 1 metric"),
    "min_weight": ("REAL", "N/m"),
    "distance_mean": ("REAL", "to the reference / bbox diagonal"),
    "distance_max": ("REAL", "to the reference / bbox diagonal"),
    "n_vertices": ("INTEGER", ""),
    "n_edges": ("INTEGER", ""),
    "message": ("TEXT", "error or status message"),
    "worker": ("TEXT", "dask worker address"),
    "host": ("TEXT", "worker host name"),
    "pid": ("INTEGER", "worker process id"),
    "started_at": ("REAL", "Unix time"),
    "finished_at": ("REAL", "Unix time"),
    "peak_rss_mb": ("REAL", "peak resident memory of the worker process during the run"),
    "params": ("TEXT", "all parameters, JSON"),
}
COLUMN_NAMES: tuple[str, ...] = tuple(COLUMNS)
_PANDAS_TYPES = {"TEXT": "object", "REAL": "float64", "INTEGER": "Int64"}


def scene_digest(scene: Scene) -> str:
    """SHA-256 of what a solve reads from a scene: vertices, faces, supports, extra loads."""
    h = hashlib.sha256()
    m = scene.mesh
    for tag, arr, dtype in (("v", m.vertices, "<f8"), ("fv", m.face_vertices, "<i8"), ("fo", m.face_offsets, "<i8"),
                            ("s", scene.supports, "u1"), ("em", scene.extra_mass, "<f8"),
                            ("pl", scene.point_loads, "<f8")):
        h.update(tag.encode())
        if arr is not None:
            a = np.ascontiguousarray(arr, dtype=dtype)
            h.update(str(a.shape).encode())
            h.update(a.tobytes())
    return h.hexdigest()


def _canonical(obj: Any) -> str:
    """Deterministic JSON (sorted keys; floats by repr; inf/nan spelled out)."""
    def fix(x: Any) -> Any:
        if isinstance(x, float) and not math.isfinite(x):
            return repr(x)
        if isinstance(x, dict):
            return {str(k): fix(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [fix(v) for v in x]
        return x
    return json.dumps(fix(obj), sort_keys=True, separators=(",", ":"), allow_nan=False)


def run_key(scene_sha: str, identity: Mapping[str, Any]) -> str:
    """The store key: SHA-256 of the scene digest and the run's identity (see
    :meth:`selfsupport.sweep.spec.RunSpec.identity`)."""
    return hashlib.sha256(_canonical({"scene": scene_sha, "run": identity}).encode()).hexdigest()


class ResultStore:
    """A sweep's SQLite store (one writer: the sweep's client process).

    Parameters
    ----------
    path
        Database file; created with its folder if missing.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(self.path, timeout=30.0, isolation_level=None)
        except (OSError, sqlite3.Error) as e:
            raise InputError(f"cannot open the result store {self.path}: {e}; check the --out folder") from None
        self._db.execute("PRAGMA journal_mode=WAL")
        # FULL: a committed run survives even an OS crash, at one fsync per run (runs take seconds)
        self._db.execute("PRAGMA synchronous=FULL")
        cols = ", ".join(f"{n} {t}" + (" PRIMARY KEY" if n == "key" else "") for n, (t, _) in COLUMNS.items())
        with self._db:
            self._db.execute(f"CREATE TABLE IF NOT EXISTS runs ({cols})")
            self._db.execute("CREATE TABLE IF NOT EXISTS sessions (session TEXT PRIMARY KEY, started_at REAL, "
                             "sweep TEXT, spec_sha256 TEXT, spec TEXT, n_runs INTEGER, n_todo INTEGER, cluster TEXT)")
            self._db.execute("CREATE TABLE IF NOT EXISTS attempts (key TEXT, session TEXT, submitted_at REAL)")
        existing = [r[1] for r in self._db.execute("PRAGMA table_info(runs)")]
        missing = [c for c in COLUMN_NAMES if c not in existing]
        with self._db:
            for c in missing:  # a store written by an older version: add the new columns
                self._db.execute(f"ALTER TABLE runs ADD COLUMN {c} {COLUMNS[c][0]}")

    # ------------------------------------------------------------------ context manager
    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> "ResultStore":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ writing
    def begin_session(self, *, sweep: str, spec_sha256: str, spec: str, n_runs: int, n_todo: int,
                      cluster: str) -> str:
        """Record an invocation; returns its id."""
        sid = f"{time.strftime('%Y%m%dT%H%M%S')}-{uuid.uuid4().hex[:8]}"
        with self._db:
            self._db.execute("INSERT INTO sessions VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                             (sid, time.time(), sweep, spec_sha256, spec, n_runs, n_todo, cluster))
        return sid

    def log_attempts(self, session: str, keys: Iterable[str]) -> None:
        """Record that ``session`` submitted these runs (before it submits them)."""
        now = time.time()
        with self._db:
            self._db.executemany("INSERT INTO attempts VALUES (?, ?, ?)", [(k, session, now) for k in keys])

    def insert(self, row: Mapping[str, Any], *, replace: bool = False) -> bool:
        """Insert one run atomically. Returns False if its key was already stored (and left
        alone, unless ``replace``)."""
        unknown = set(row) - set(COLUMN_NAMES)
        if unknown:
            raise InputError(f"unknown result column(s) {sorted(unknown)}")
        if not row.get("key"):
            raise InputError("a result row needs its key")
        names = [c for c in COLUMN_NAMES if c in row]
        values = [_sql_value(row[c]) for c in names]
        verb = "INSERT OR REPLACE" if replace else "INSERT"
        tail = "" if replace else " ON CONFLICT(key) DO NOTHING"
        with self._db:
            cur = self._db.execute(f"{verb} INTO runs ({', '.join(names)}) VALUES ({', '.join('?' * len(names))}){tail}",
                                   values)
        return cur.rowcount == 1

    # ------------------------------------------------------------------ reading
    def keys(self) -> set[str]:
        return {r[0] for r in self._db.execute("SELECT key FROM runs")}

    def statuses(self) -> dict[str, str]:
        return dict(self._db.execute("SELECT key, status FROM runs"))

    def count(self) -> int:
        return int(self._db.execute("SELECT COUNT(*) FROM runs").fetchone()[0])

    def attempts(self) -> list[tuple[str, str, float]]:
        return list(self._db.execute("SELECT key, session, submitted_at FROM attempts ORDER BY rowid"))

    def sessions(self) -> list[tuple[str, float, int, int]]:
        return list(self._db.execute("SELECT session, started_at, n_runs, n_todo FROM sessions ORDER BY started_at"))

    def frame(self, keys: Iterable[str] | None = None):
        """The runs as a pandas DataFrame (all columns, store types), optionally only ``keys``,
        ordered by finishing time."""
        import pandas as pd

        rows = self._db.execute(f"SELECT {', '.join(COLUMN_NAMES)} FROM runs ORDER BY finished_at, key").fetchall()
        df = pd.DataFrame.from_records(rows, columns=list(COLUMN_NAMES))
        if keys is not None:
            wanted = set(keys)
            df = df[df["key"].isin(wanted)].reset_index(drop=True)
        return _typed(df)

    # ------------------------------------------------------------------ export
    def export_csv(self, path: str | Path, keys: Iterable[str] | None = None) -> Path:
        """Write the runs as CSV (floats round-trip exactly with :func:`read_export`)."""

        path = Path(path)
        atomic_write_text(path, self.frame(keys).to_csv(index=False, float_format="%.17g"))
        return path

    def export_parquet(self, path: str | Path, keys: Iterable[str] | None = None) -> Path:
        """Write the runs as Parquet (pyarrow)."""


        path = Path(path)
        buf = io.BytesIO()
        self.frame(keys).to_parquet(buf, index=False, engine="pyarrow")
        atomic_write_bytes(path, buf.getvalue())
        return path


def _sql_value(v: Any) -> Any:
    if isinstance(v, str) and not v:
        return None  # one spelling of "nothing": CSV cannot tell "" from NULL
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        v = float(v)
    if isinstance(v, float) and math.isnan(v):
        return None
    if isinstance(v, (dict, list, tuple)):
        return _canonical(v)
    return v


def _typed(df):
    """Give every column its store type (nullable integers, float, string objects)."""
    for c in COLUMN_NAMES:
        kind = _PANDAS_TYPES[COLUMNS[c][0]]
        if kind == "object":
            df[c] = df[c].astype(object).where(df[c].notna(), None)
        else:
            df[c] = df[c].astype(kind)
    return df


def read_export(path: str | Path):
    """Read a CSV or Parquet export back into a DataFrame with the store's column types."""
    import pandas as pd

    path = Path(path)
    readers = {".csv": lambda p: pd.read_csv(p, keep_default_na=False,
                                              na_values=[""], dtype={c: str for c, (t, _) in COLUMNS.items() if t == "TEXT"}),
               ".parquet": lambda p: pd.read_parquet(p, engine="pyarrow")}
    try:
        reader = readers[path.suffix.lower()]
    except KeyError:
        raise InputError(f"{path}: unknown export type {path.suffix!r}; use .csv or .parquet") from None
    return _typed(reader(path))
