"""The size guard: refuse a solve whose memory would exceed the machine before allocating it.

A solve's peak memory grows with the mesh (the Step-2 normal equations and their Cholesky
factor dominate in the staggered method, MUMPS's factor of the KKT system in IPOPT), so it
is estimated from the vertex count: each method's :class:`~selfsupport.methods.Capabilities`
``bytes_per_vertex`` is a rate of peak resident set size per vertex, rounded up from solves of
domes (the staggered method about 10-13 KB per vertex, IPOPT about 74 KB). A rate per vertex,
because a solve's memory grows about linearly with the mesh: ``python -m studies.scaling``
records the peak RSS of every size it solves (``peak_rss_mib`` in ``scaling.csv``) and fits its
exponent (``memory_exponent`` in ``scaling_exponents.csv``, near 1). An estimate above the memory available (or
``--max-memory``) is refused with one line instead of ending in an out-of-memory kill, which the
kernel delivers without a word.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from selfsupport.core.errors import TooLarge
from selfsupport.core.linalg import DENSE_ROW_MIN
from selfsupport.core.mesh import PolyMesh
from selfsupport.core.subdivision import subdivided_vertex_count
from selfsupport.methods import capabilities
from selfsupport.methods.choice import AUTO, CANDIDATES, candidates
from selfsupport.methods.polish import DIRECT_CASES_MAX

GIB = 1024.0 ** 3
#: The interpreter and libraries before any mesh, with a margin (the scaling study's
#: ``rss_before_mib`` is about 100 MB).
BASE_BYTES = 150e6


#: Safety margin on the per-case factors of :func:`case_factor`.
CASE_MARGIN = 1.25


def case_factor(n_cases: int) -> float:
    """How many single-case solves of the same mesh a solve of ``n_cases`` load cases weighs.
    Each case has its own weight fit and factors (linear); up to
    :data:`~selfsupport.methods.polish.DIRECT_CASES_MAX` cases the joint polish also factors a
    matrix whose blocks pair every two cases (quadratic), so the factor is ``c (1 + c)`` up to
    there and ``c`` beyond, each with the margin :data:`CASE_MARGIN`.

    >>> case_factor(1), case_factor(2), case_factor(4), case_factor(5)
    (1.0, 7.5, 25.0, 6.25)
    """
    c = max(int(n_cases), 1)
    if c == 1:
        return 1.0
    return CASE_MARGIN * c * (1 + c) if c <= DIRECT_CASES_MAX else CASE_MARGIN * c


def dense_row_bytes(edges, n_vertices: int) -> float:
    """Memory [bytes] of the weight fit's dense rows (:data:`~selfsupport.core.linalg.DENSE_ROW_MIN`)
    for a mesh with these ``edges``: three rows per vertex of higher valence, each kept as an
    ``n_edges × k`` block (``k`` the dense rows) in a few copies, with a ``k × k`` matrix."""
    edges = np.asarray(edges).reshape(-1, 2)
    k = 3 * int(np.sum(np.bincount(edges.ravel(), minlength=n_vertices) > DENSE_ROW_MIN))
    return 4 * 8.0 * k * (len(edges) + k)


def estimate_solve_bytes(n_vertices: int, method: str = "staggered", n_cases: int = 1,
                         extra_bytes: float = 0.0) -> float:
    """Estimated peak memory [bytes] of solving a mesh of ``n_vertices`` with ``method`` under
    ``n_cases`` load cases (:func:`case_factor`), plus ``extra_bytes`` (e.g. :func:`dense_row_bytes`).

    >>> round(estimate_solve_bytes(200_000) / 1e9, 2)  # rounded-up rate: an upper estimate
    3.35
    """
    rate = bytes_per_vertex(method, n_vertices)
    return BASE_BYTES + rate * float(n_vertices) * case_factor(n_cases) + float(extra_bytes)


def bytes_per_vertex(method: str, n_vertices: int | None = None) -> float:
    """Peak bytes per vertex of a one-case solve by the registered ``method``; ``"auto"``: the
    larger rate of the methods it may pick for a mesh of ``n_vertices`` (any size if not given;
    :func:`~selfsupport.methods.choice.candidates`: a small mesh's check then loads no other
    method's module)."""
    names = (candidates(n_vertices) if n_vertices is not None else CANDIDATES) if method == AUTO else (method,)
    return max(capabilities(name).bytes_per_vertex for name in names)


def available_bytes() -> float:
    """Memory this process may still use [bytes]: the kernel's ``MemAvailable``, capped by a
    cgroup (v2 or v1) limit minus its usage when one is set; ``inf`` when unknown."""
    avail = float("inf")
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail = float(line.split()[1]) * 1024.0
                break
    except OSError:
        try:
            avail = float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (ValueError, OSError, AttributeError):
            pass
    for limit_file, usage_file in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                                   ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            limit = Path(limit_file).read_text().strip()
            if limit != "max" and float(limit) < 1e18:  # (v1 writes a huge number for "none")
                avail = min(avail, float(limit) - float(Path(usage_file).read_text().strip()))
        except (OSError, ValueError):
            continue
    return avail


def check_memory(n_vertices: int, method: str = "staggered", max_memory: float | None = None,
                 n_cases: int = 1, extra_bytes: float = 0.0, what: str | None = None) -> float:
    """Refuse (:class:`~selfsupport.core.errors.TooLarge`, one line) a solve whose estimated memory
    (:func:`estimate_solve_bytes`) exceeds ``max_memory`` [GiB] or, without it, the memory
    available now. Returns the estimate [bytes]. The guard of every operation that makes a mesh
    (subdividing, a constructed disk): ``what`` names it in the message (default: the solve)."""
    need = estimate_solve_bytes(n_vertices, method, n_cases, extra_bytes)
    has = available_bytes() if max_memory is None else float(max_memory) * GIB
    if need > has:
        where = (f"--max-memory allows {_gib(has)} GiB" if max_memory is not None
                 else f"this machine has {_gib(has)} GiB available")
        cases = f" under {n_cases:,} load cases" if n_cases > 1 else ""
        named = "" if method == AUTO else f"{method} "  # (auto: the method is not chosen yet)
        raise TooLarge(f"{what or f'a {named}solve'} of {n_vertices:,} vertices{cases} needs about {_gib(need)} GiB, {where}; "
                       f"use --max-memory{', a coarser mesh or fewer load cases' if cases else ' or a coarser mesh'}")
    return need


def _gib(n_bytes: float) -> str:
    """GiB with one decimal, small amounts with two significant digits (0.05, not 0.1)."""
    x = n_bytes / GIB
    return f"{x:.1f}" if x >= 1 else f"{x:.2g}"


def check_scene_spec(spec: str, method: str = "staggered", max_memory: float | None = None) -> None:
    """:func:`check_memory` for a built-in shape ``shape:NAME:VERTICES`` before it is built
    (building it is already an allocation of its size); files are checked once read."""
    parts = spec.split(":")
    if spec.startswith("shape:") and len(parts) == 3 and parts[2].strip().isdigit():
        check_memory(int(parts[2]), method, max_memory)


def check_subdivision(mesh: PolyMesh, levels: int, max_memory: float | None = None) -> float:
    """:func:`check_memory` of a solve of ``mesh`` subdivided ``levels`` times
    (:func:`~selfsupport.core.subdivision.subdivide_scene`), before any step."""
    return check_memory(subdivided_vertex_count(mesh, levels), "multilevel", max_memory,
                        what=f"subdividing {levels} times gives a mesh whose solve")
