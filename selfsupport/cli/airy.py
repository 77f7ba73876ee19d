"""``selfsupport airy`` and ``selfsupport construct`` (picked up by :func:`selfsupport.cli.discover_commands`).

::

    selfsupport airy NET.json --out AIRY.json [--stress PHI.obj] [--reciprocal RECIP.obj]
                     [--polar POLAR.obj] [--vector-fields VF.txt] [--up AXIS] [--areas RULE] [--tol T]
    selfsupport construct --out NET.json (--disk RINGS | --random N | --points FILE)
                     [--radius R] [--seed S] [--phi NAME | --phi-values FILE]
                     [--load F | --self-weight [--density RHO] [--thickness T]] [--boundary-height H] [--tol T]

``airy`` analyses a network file (paper §2): the Airy stress surface Φ, the reciprocal force
diagram, H_rel, K_Φ and the balance (6); ``AIRY.json`` holds ``phi`` (per vertex),
``reciprocal_vertices`` (per face, network face order), ``H_rel``, ``K_phi``,
``balance_residual`` (per vertex; ``null`` where undefined), ``closure_residual`` (the worst
relative horizontal imbalance), ``convex``, and more (periods around holes and interior supports,
cut edges, ``corner_phi`` and ``phi_copies`` — Φ on the cover, cut open along cuts with a period —,
crease weights, principal directions), and whether the network is in equilibrium to ``--tol``
(``in_equilibrium``, ``max_relative_error``, ``tol``). ``construct`` builds a self-supporting
network from a convex Airy function (§2.5) and writes it in the network format, with its
``status``: ``converged`` when it is in equilibrium to ``--tol``, else ``failed`` (exit 4).

Exit codes: 0 on success; for ``airy`` also 0 when Φ is not convex (that is a finding, printed);
4 when the network is not in equilibrium (``airy``: Φ and the reciprocal diagram exist only for a
network in equilibrium, so the analysis is written but describes residuals; ``construct``: its
round-off); 2 bad input.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from selfsupport.analysis import airy, construct_detailed, curvatures, reciprocal, write_vector_fields
from selfsupport.api import DEFAULT_CHECK_TOL
from selfsupport.cli.common import (
    EXIT_CODES,
    STATUS_EXIT,
    Command,
    _err,
    add_network_out_arguments,
    built_status,
    check_network_out,
    not_in_equilibrium_line,
    number_in,
    positive_float,
    positive_int,
    print_table,
    tolerance,
    write_network_out,
)
from selfsupport.core.errors import InputError
from selfsupport.core.loads import SelfWeight
from selfsupport.core.shapes import disk_points
from selfsupport.io import read_network, write_mesh
from selfsupport.io.atomic import atomic_write_text
from selfsupport.io.axes import rotation
from selfsupport.io.network_json import to_jsonable
from selfsupport.io.safety import check_outputs
from selfsupport.methods.memory import check_memory

__all__ = ["COMMANDS", "PHI_NAMES", "INTEGRATION_NAMES", "add_airy_arguments", "run_airy", "add_construct_arguments", "run_construct", "airy_document"]


#: ``--phi`` choices, kept here so that building the parser imports no numerics (a test checks
#: they equal ``selfsupport.analysis.construction.PHI_FUNCTIONS``)
PHI_NAMES = ("cosh", "elliptic", "paraboloid", "quartic")
#: ``--integration`` choices (``selfsupport.analysis.airy.INTEGRATIONS``, checked by a test too)
INTEGRATION_NAMES = ("auto", "tree", "least-squares")


# ----------------------------------------------------------------------------------- airy
def add_airy_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``selfsupport airy``."""
    p.add_argument("network", metavar="NET.json", help="network file (JSON, as written by 'selfsupport solve')")
    p.add_argument("--out", "-o", required=True, metavar="AIRY.json", help="analysis file to write (JSON)")
    p.add_argument("--stress", metavar="PHI.obj", default=None,
                   help="also write the Airy stress surface (x, y, φ) as a mesh (.obj .ply .off); planar faces, vertices "
                        "on cuts with a period appear once per side (appended after the network's)")
    p.add_argument("--reciprocal", metavar="RECIP.obj", default=None,
                   help="also write the reciprocal force diagram (one vertex per face, one cell per interior vertex)")
    p.add_argument("--polar", metavar="POLAR.obj", default=None,
                   help="also write the polar dual Φ* w.r.t. z = (x²+y²)/2 (planar faces)")
    p.add_argument("--vector-fields", metavar="VF.txt", default=None,
                   help="also write the relative principal directions per face, like the paper's -vf.txt")
    p.add_argument("--up", default="z", metavar="AXIS",
                   help="vertical axis of the written meshes and vector fields (default z; the paper's files: -y)")
    p.add_argument("--areas", default="voronoi", metavar="RULE",
                   help="top-view vertex areas for K_Φ and F = load/area (voronoi or barycentric)")
    p.add_argument("--integration", choices=INTEGRATION_NAMES, default="auto",
                   help="face planes by spanning-tree integration, least squares over the dual graph, or auto "
                        "(least squares unless the input is integrable to round-off)")
    p.add_argument("--no-directions", action="store_true",
                   help="skip the Hessian fits and relative principal directions")
    p.add_argument("--tol", type=tolerance, default=None, metavar="T",
                   help="max relative error of a network in equilibrium (default 1e-6, as 'check'); exit 4 above it")


def _nan_list(a: np.ndarray | None) -> Any:
    return None if a is None else np.asarray(a, float)  # to_jsonable writes NaN as null


def airy_document(network, res, rd, cv) -> dict[str, Any]:
    """The ``AIRY.json`` content for an analysed network (see the module docstring)."""
    periods = [{"kind": p.kind, "vertices": p.vertices, "gradient": p.gradient, "offset": p.offset,
                "thrust": p.thrust, "moment": p.moment, "cut_edge": p.cut_edges} for p in res.periods]
    doc: dict[str, Any] = {
        "phi": res.phi,
        "corner_phi": res.corner_phi,
        "phi_copies": {"vertex": res.cover_parent[network.mesh.n_vertices:],
                       "phi": res.cover_phi[network.mesh.n_vertices:]},
        "reciprocal_vertices": res.reciprocal_vertices,
        "face_offsets": res.face_offsets,
        "polar_vertices": rd.polar_vertices,
        "H_rel": _nan_list(cv.H_rel),
        "K_phi": _nan_list(cv.K_phi),
        "balance_residual": _nan_list(cv.balance_residual),
        "closure_residual": res.max_closure_residual,
        "closure_residuals": _nan_list(res.closure_residual),
        "convex": bool(res.convex),
        "orientation": res.orientation,
        "edges": network.mesh.edges,
        "crease_weights": _nan_list(res.crease_weights),
        "reciprocal_cell_areas": _nan_list(rd.cell_areas),
        "laplacian_phi": cv.laplacian_phi,
        "laplacian_s": cv.laplacian_s,
        "vertex_areas": cv.areas,
        "load_density": cv.load_density,
        "cut_edges": res.cut_edges,
        "periods": periods,
        "nonplanar_faces": res.nonplanar_faces,
        "split_edges": res.split_edges,
        "split_edge_weights": res.split_edge_weights,
        "summary": {**res.summary(), "max_balance_residual": cv.max_balance_residual,
                    "max_identity_residual": cv.max_identity_residual,
                    "max_reciprocal_edge_residual": float(np.max(rd.edge_residual)) if rd.edge_residual.size else 0.0},
        "conventions": {
            "reciprocal_vertices": "gradient of Φ on each face (network face order); across interior edge k, "
                                   "R[left] - R[right] = w_k J (x_j - x_i) for edges[k] = (i, j), J = +90° rotation",
            "balance_residual": "|2 K_phi H_rel - F| / |F| with F = load / top-view vertex area (eq. 6), "
                                "at free vertices, summed over each vertex's star on its own branch of Φ",
            "closure_residual": "max over free vertices of |Σ_j w_ij (x_j - x_i)| / Σ_j |w_ij| |x_j - x_i|",
            "phi": "per vertex, on the branch of its lowest-numbered face; corner_phi per corner (faces in order, "
                   "corners concatenated) is single valued per face; phi_copies lists the second branches of the "
                   "vertices on cuts with a period (the --stress mesh appends them as vertices n, n+1, ...)",
        },
    }
    if cv.principal_directions is not None:
        doc["principal_curvatures"] = _nan_list(cv.principal_curvatures)
        doc["principal_directions"] = _nan_list(cv.principal_directions)
    return doc


def run_airy(args: argparse.Namespace) -> int:
    """Analyse a network file and write ``AIRY.json`` (plus the optional meshes)."""

    rotation(args.up, what="--up")  # fail before the work, with the valid names
    check_outputs([("--out", args.out), ("--stress", args.stress), ("--reciprocal", args.reciprocal),
                   ("--polar", args.polar), ("--vector-fields", args.vector_fields)], [("NET.json", args.network)])
    if args.vector_fields and args.no_directions:
        raise InputError("--vector-fields needs the principal directions; drop --no-directions")
    if not Path(args.network).exists():
        raise InputError(f"{args.network}: no such file; give a network file written by 'selfsupport solve'")
    t0 = time.perf_counter()
    net = read_network(args.network)
    res = airy(net, integration=args.integration)
    rd = reciprocal(res)
    cv = curvatures(net, res, areas=args.areas, directions=not args.no_directions)
    seconds = time.perf_counter() - t0
    doc = airy_document(net, res, rd, cv)
    doc["summary"]["seconds"] = seconds
    # Φ is the Airy surface of a network in equilibrium only; of any other its creases are not the
    # network's weights, so its convexity says nothing about tension
    tol = DEFAULT_CHECK_TOL if args.tol is None else args.tol
    balanced = net.in_equilibrium(tol)
    doc.update(in_equilibrium=balanced, max_relative_error=net.max_relative_error(), tol=tol)
    atomic_write_text(args.out, json.dumps(to_jsonable(doc), allow_nan=False, separators=(",", ":")))
    written = [args.out]
    if args.stress:
        write_mesh(args.stress, res.stress_mesh(), up=args.up)
        written.append(args.stress)
    if args.reciprocal:
        write_mesh(args.reciprocal, rd.mesh("flat"), up=args.up)
        written.append(args.reciprocal)
    if args.polar:
        write_mesh(args.polar, rd.mesh("polar"), up=args.up)
        written.append(args.polar)
    if args.vector_fields:
        write_vector_fields(args.vector_fields, net, cv, up=args.up)
        written.append(args.vector_fields)
    rows = [("vertices / faces", f"{net.mesh.n_vertices} / {net.mesh.n_faces}"),
            ("in equilibrium (max rel. error)", f"{'yes' if balanced else 'NO'} ({net.max_relative_error():.2e}, "
                                                f"tol {tol:g})"),
            ("Φ convex (all creases >= 0)", ("yes" if res.convex else "NO (some weights are tensile)") if balanced
             else "unknown (no equilibrium)"),
            ("closure residual (horizontal equilibrium)", f"{res.max_closure_residual:.2e}"),
            ("jump condition residual (rel.)", f"{res.max_edge_residual:.2e} ({res.integration})"),
            ("balance 2 K_Φ H_rel = F (eq. 6), max rel.", f"{cv.max_balance_residual:.2e}"),
            ("Δφ φ = 2 × reciprocal cell area, max rel.", f"{cv.max_identity_residual:.2e}"),
            ("periods (holes, interior supports)", str(len(res.periods))),
            ("cut edges / vertices of Φ copied along cuts", f"{res.cut_edges.size} / {res.n_cover_copies}"),
            ("non-planar polygon faces (split)", str(res.nonplanar_faces.size)),
            ("time", f"{seconds:.3f} s"),
            ("written", ", ".join(written))]
    print_table(f"selfsupport airy {args.network}", rows)
    if not balanced:
        _err(f"{args.network} is NOT in equilibrium (max relative error {net.max_relative_error():.2e} > tol {tol:g}): "
             f"it has no Airy stress surface, so {args.out} "
             "describes residuals only; solve it to equilibrium first (selfsupport solve NET.json) or give a "
             "larger --tol")
        return EXIT_CODES["not_converged"]
    return EXIT_CODES["ok"]


# ------------------------------------------------------------------------------ construct
def add_construct_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``selfsupport construct``."""
    add_network_out_arguments(p)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--disk", type=positive_int, metavar="RINGS",
                     help="top view: the ring points of a disk (1 + 3 RINGS (RINGS+1) points)")
    src.add_argument("--random", type=positive_int, metavar="N",
                     help="top view: N random points in a disk, plus points on its rim")
    src.add_argument("--points", metavar="FILE",
                     help="top view: a text file with x y per line ('#' comments) or a .npy array")
    p.add_argument("--radius", type=positive_float, default=5.0, help="disk radius for --disk/--random [m] (default 5)")
    p.add_argument("--seed", type=number_in("[0, inf)", integer=True), default=0, help="random seed for --random (default 0)")
    phi = p.add_mutually_exclusive_group()
    phi.add_argument("--phi", choices=PHI_NAMES, default="paraboloid",
                     help="convex Airy function φ(x, y) (default paraboloid: φ = (x²+y²)/2)")
    phi.add_argument("--phi-values", metavar="FILE", help="φ sampled at the points, one value per line")
    ld = p.add_mutually_exclusive_group()
    ld.add_argument("--load", type=number_in("(-inf, 0)", what="negative (downward)"), default=None, metavar="F",
                    help="load per unit top-view area [N/m², negative = down; write --load=-500] (default -1000)")
    ld.add_argument("--self-weight", action="store_true",
                    help="self-weight rho·t·g per unit surface area, iterated with the geometry")
    p.add_argument("--density", type=positive_float, default=2000.0, help="rho for --self-weight [kg/m³]")
    p.add_argument("--thickness", type=positive_float, default=0.1, help="t for --self-weight [m]")
    p.add_argument("--boundary-height", type=number_in("(-inf, inf)"), default=0.0, metavar="H", help="height of the supports [m]")
    p.add_argument("--rise", type=positive_float, default=None, metavar="H",
                   help="scale φ so that the crown stands H above the supports (default: a fifth of the plan's "
                        "bounding-box diagonal); weights scale with φ, heights inversely")
    p.add_argument("--tol", type=tolerance, default=None, metavar="T",
                   help="max relative error that counts as in equilibrium (default 1e-6, as 'check')")


def _read_points(path: str) -> np.ndarray:
    p = Path(path)
    if not p.exists():
        raise InputError(f"--points {path}: no such file")
    try:
        a = np.load(p) if p.suffix.lower() == ".npy" else np.loadtxt(p, comments="#", ndmin=2)
    except (ValueError, OSError) as e:
        raise InputError(f"--points {path}: cannot read points ({e}); write x y per line") from None
    if a.ndim != 2 or a.shape[1] < 2:
        raise InputError(f"--points {path}: expected x y per line, got an array of shape {a.shape}")
    return a[:, :2].astype(float)


def _random_disk(n: int, radius: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    k = max(8, int(np.ceil(2 * np.sqrt(np.pi * n))))  # rim spacing ~ interior spacing
    t = 2 * np.pi * np.arange(k) / k
    rim = radius * np.c_[np.cos(t), np.sin(t)]
    r = radius * np.sqrt(rng.uniform(0, 1, n)) * (1 - 0.5 / np.sqrt(n))
    a = rng.uniform(0, 2 * np.pi, n)
    return np.vstack([rim, np.c_[r * np.cos(a), r * np.sin(a)]])


def run_construct(args: argparse.Namespace) -> int:
    """Build a network with the §2.5 construction and write it."""
    check_network_out(args.out, args.format, [("--points", args.points), ("--phi-values", args.phi_values)])
    if args.disk is not None or args.random is not None:  # (the size guard of a solve, before the points are made)
        n = 1 + 3 * args.disk * (args.disk + 1) if args.disk is not None else args.random
        check_memory(n, "staggered", what=f"the construction ({'--disk' if args.disk is not None else '--random'})")
    if args.disk is not None:
        pts = disk_points(args.disk, radius=args.radius)
    elif args.random is not None:
        pts = _random_disk(args.random, args.radius, args.seed)
    else:
        pts = _read_points(args.points)
    if args.phi_values:
        try:
            phi: Any = np.loadtxt(args.phi_values, comments="#", ndmin=1).astype(float).ravel()
        except (ValueError, OSError) as e:
            raise InputError(f"--phi-values {args.phi_values}: cannot read values ({e}); write one number per line") from None
        phi_name = args.phi_values
    else:
        phi, phi_name = args.phi, args.phi
    load: Any = SelfWeight(density=args.density, thickness=args.thickness) if args.self_weight else (
        -1000.0 if args.load is None else args.load)
    t0 = time.perf_counter()
    rise = args.rise if args.rise is not None else 0.2 * float(np.linalg.norm(np.ptp(pts, axis=0)))
    c = construct_detailed(pts, phi, load=load, boundary_heights=args.boundary_height, rise=rise)
    seconds = time.perf_counter() - t0
    net = c.network
    tol = DEFAULT_CHECK_TOL if args.tol is None else args.tol
    status = built_status(net, tol)
    write_network_out(args.out, net, args.format, status=status, tol=tol, construction={
        "phi": phi_name, "load": "self_weight" if args.self_weight else load,
        "density": args.density if args.self_weight else None,
        "thickness": args.thickness if args.self_weight else None,
        "boundary_height": args.boundary_height, "rise": rise, "zero_force_edges": c.zero_force_edges,
        "load_rounds": c.load_rounds, "seconds": seconds},
        max_relative_error=net.max_relative_error(), min_weight=net.min_weight())
    rows = [("points / triangles / edges", f"{net.mesh.n_vertices} / {net.mesh.n_faces} / {net.mesh.n_edges}"),
            ("Airy function", str(phi_name)),
            ("supports (boundary)", str(int(net.supports.sum()))),
            ("max relative error", f"{net.max_relative_error():.2e}"),
            ("min weight", f"{net.min_weight():.4g} N/m"),
            ("zero-force edges", str(c.zero_force_edges.size)),
            ("height range", f"{net.vertices[:, 2].min():.4g} .. {net.vertices[:, 2].max():.4g} m"),
            ("load rounds", str(c.load_rounds)),
            ("time", f"{seconds:.3f} s"),
            ("written", args.out)]
    print_table("selfsupport construct", rows)
    if status != "converged":
        z = net.vertices[:, 2]
        _err(not_in_equilibrium_line(net, tol, args.out, (
            f"its heights are {z.min():.4g} .. {z.max():.4g} m for a rise of {rise:.4g} m, so round-off may be what "
            "is left; try --boundary-height nearer 0, a larger --rise or a larger --tol")))
    return STATUS_EXIT[status]


COMMANDS: dict[str, Command] = {
    "airy": Command("Airy stress surface, reciprocal diagram and curvatures of a network file (paper §2)",
                    add_airy_arguments, run_airy),
    "construct": Command("build a self-supporting network from a convex Airy function (paper §2.5)",
                         add_construct_arguments, run_construct),
}
