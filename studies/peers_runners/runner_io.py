"""Shared plumbing of the runners: arguments, the problem file and the result file.

Plain standard library and numpy only: it runs in the peers' environment too.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import traceback
from pathlib import Path
from typing import Any

import numpy as np


def parse_args(description: str) -> argparse.Namespace:
    """``PROBLEM.json RESULT.json [--time-limit S]``."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("problem")
    p.add_argument("result")
    p.add_argument("--time-limit", type=float, default=300.0)
    return p.parse_args()


def installed_version(distribution: str) -> str:
    """The installed version of a package (the one the study pinned in its environment)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(distribution)
    except PackageNotFoundError:
        return "unknown"


def read_problem(path: str | os.PathLike) -> dict[str, Any]:
    """The problem as numpy arrays: ``vertices (n,3)``, ``edges (m,2)``, ``faces`` (lists),
    ``supports`` (indices), ``loads (n,)`` signed [N], negative down."""
    d = json.loads(Path(path).read_text(encoding="utf-8"))
    return {
        "name": d["name"],
        "vertices": np.asarray(d["vertices"], float),
        "edges": np.asarray(d["edges"], int).reshape(-1, 2),
        "faces": [list(map(int, f)) for f in d["faces"]],
        "supports": np.asarray(d["supports"], int),
        "loads": np.asarray(d["loads"], float),
        "density": float(d.get("density", 2000.0)),
        "thickness": float(d.get("thickness", 0.1)),
    }


def write_result(path: str | os.PathLike, **result: Any) -> None:
    """Write the result JSON atomically (a half-written file would read as a crash)."""
    def plain(v: Any) -> Any:
        if isinstance(v, np.ndarray):
            return v.tolist()
        if isinstance(v, (np.floating, np.integer)):
            return v.item()
        return v

    text = json.dumps({k: plain(v) for k, v in result.items()})
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)
    os.replace(tmp, path)


def fail(path: str | os.PathLike, tool: str, exc: BaseException) -> None:
    """Record a failure as a result (status ``failed``): the exception's first line and the
    tool's function the runner called when it was raised (a bare ``KeyError: 1936`` says nothing)."""
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" (in {frames[1].name})" if len(frames) > 1 else ""
    message = (f"{type(exc).__name__}: {exc}".splitlines() or [type(exc).__name__])[0] + where
    write_result(path, tool=tool, status="failed", message=message,
                 time_s=float("nan"), vertices=[], edges=[], weights=[])
    print(f"{tool}: {type(exc).__name__}: {exc}", file=sys.stderr)
