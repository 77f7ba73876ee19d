"""``selfsupport koebe`` (picked up by :func:`selfsupport.cli.discover_commands`).

::

    selfsupport koebe --out NET.json [--example NAME | --mesh FILE [--up AXIS]] [--alpha A]
                      [--kind tangent|inscribed] [--n N] [--hole H] [--spacing S] [--mobius NAME]
                      [--load-density Q] [--loads reciprocal|top-view] [--tol T]
                      [--phi-out PHI.obj] [--partner-out R.obj] [--network-out S.obj]

The paper's §5 family (Fig. 15): from a Koebe mesh Φ (a built-in example or a quad mesh file)
its minimal partner R (the polar of the Christoffel dual of Φ's polar mesh) and the thrust
network ``−(Φ + αR)`` (z up) in equilibrium for unit load, written in the network format with
a ``koebe`` key (α, φ and r per vertex, K_Φ per vertex, the Koenigs defect and the other
evidence) and its ``status``: ``converged`` when it is in equilibrium to ``--tol``, else ``failed``.
Exit 0 when it is in equilibrium, 4 when not (the file is written anyway: rounded coordinates, or
top-view loads on a mesh with K_Φ ≠ 1), 2 on bad input (including a mesh whose polar mesh is not
Koenigs).
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from selfsupport.api import DEFAULT_CHECK_TOL, koebe
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
from selfsupport.core.evidence import face_nonplanarity
from selfsupport.io import write_mesh
from selfsupport.io.axes import rotation
from selfsupport.io.safety import check_outputs

__all__ = ["COMMANDS", "EXAMPLE_NAMES", "KIND_NAMES", "MOBIUS_NAMES", "LOAD_RULE_NAMES", "add_koebe_arguments",
           "run_koebe"]

#: choices, kept here so that building the parser imports no numerics (a test checks they equal
#: the registries in ``selfsupport.analysis.koebe``)
EXAMPLE_NAMES = ("enneper", "grid")
KIND_NAMES = ("tangent", "inscribed")
MOBIUS_NAMES = ("identity", "inversion")
LOAD_RULE_NAMES = ("reciprocal", "top-view")
#: ``--alpha`` range: beyond it αR is more than a million times Φ's height range, and the round-off
#: of the heights (which grows with α: 1.2e-12 × α on enneper) swamps the equilibrium, up to
#: overflow near 1e200
ALPHA_RANGE = "[-1e6, 1e6]"


def add_koebe_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``selfsupport koebe``."""
    add_network_out_arguments(p)
    src = p.add_mutually_exclusive_group()
    src.add_argument("--example", choices=EXAMPLE_NAMES, default=None,
                     help="built-in Koebe mesh (default enneper: the layout of the paper's Fig. 15)")
    src.add_argument("--mesh", metavar="FILE", default=None,
                     help="a planar-quad Koebe mesh Φ (.obj .ply .off); a dome is taken as the α = 0 thrust "
                          "network and reflected into Φ (the paper's files: --up=-y)")
    p.add_argument("--up", default=None, metavar="AXIS",
                   help="vertical axis of --mesh and of the written meshes (default z)")
    p.add_argument("--alpha", type=number_in(ALPHA_RANGE), default=1.0,
                   help=f"family parameter α in {ALPHA_RANGE} (default 1; R is scaled to Φ's height range)")
    p.add_argument("--kind", choices=KIND_NAMES, default="tangent",
                   help="example meshes: edges tangent to z = (x²+y²)/2 (a Koebe mesh, default) or vertices on it")
    p.add_argument("--n", type=positive_int, default=None, help="example grid: vertices per side")
    p.add_argument("--hole", type=number_in("[0, inf)", integer=True), default=None, help="example grid: central vertices per side left out")
    p.add_argument("--spacing", type=positive_float, default=None, help="example grid: spacing of the circles")
    p.add_argument("--mobius", choices=MOBIUS_NAMES, default=None, help="example grid: Möbius map of the top view")
    p.add_argument("--koenigs-tol", type=positive_float, default=1e-8, metavar="T",
                   help="largest Koenigs defect (log ratio) accepted for Φ's polar mesh (default 1e-8; files with "
                        "rounded coordinates need more, e.g. 1e-3 for the paper's 6-digit OBJ)")
    p.add_argument("--load-density", type=positive_float, default=1.0, metavar="Q",
                   help="load per unit top-view area [N/m²] (default 1: unit load)")
    p.add_argument("--loads", choices=LOAD_RULE_NAMES, default="reciprocal",
                   help="nodal loads: reciprocal-cell areas (exact for every α, default) or top-view areas "
                        "(exact only where K_Φ = 1, i.e. inscribed meshes)")
    p.add_argument("--tol", type=tolerance, default=None, metavar="T",
                   help="max relative error that counts as in equilibrium (default 1e-6, as 'check')")
    p.add_argument("--phi-out", metavar="PHI.obj", default=None, help="also write the Airy surface Φ (convex)")
    p.add_argument("--partner-out", metavar="R.obj", default=None, help="also write the minimal partner R (x, y, r)")
    p.add_argument("--network-out", metavar="S.obj", default=None, help="also write the network as a mesh")


def run_koebe(args: argparse.Namespace) -> int:
    """Build the family member and write it."""
    up = "z" if args.up is None else args.up
    rotation(up, what="--up")
    outputs = [("--out", args.out), ("--phi-out", args.phi_out), ("--partner-out", args.partner_out),
               ("--network-out", args.network_out)]
    check_outputs(outputs, [("--mesh", args.mesh)])
    check_network_out(args.out, args.format, [("--mesh", args.mesh)])
    named = [(w, os.path.realpath(p)) for w, p in outputs if p is not None]
    for k, (w, p) in enumerate(named):
        for w2, p2 in named[:k]:
            if p == p2:
                raise InputError(f"{w2} and {w} name the same file {p}; give each output its own path")
    grid = {k: getattr(args, k) for k in ("n", "hole", "spacing", "mobius") if getattr(args, k) is not None}
    if args.mesh is not None and (grid or args.kind != "tangent"):
        raise InputError("--kind, --n, --hole, --spacing and --mobius describe a built-in example; drop them with --mesh")
    source = args.mesh if args.mesh is not None else (args.example or "enneper")
    t0 = time.perf_counter()
    fam = koebe(source, alpha=args.alpha, kind=args.kind, up=up, load_density=args.load_density, loads=args.loads,
                koenigs_tol=args.koenigs_tol, **grid)
    seconds = time.perf_counter() - t0
    net, R = fam.network, fam.partner
    mesh_phi = net.mesh.with_vertices(np.c_[net.vertices[:, :2], fam.phi])
    mesh_r = net.mesh.with_vertices(np.c_[net.vertices[:, :2], fam.r])
    K = fam.gauss_curvature[~np.isnan(fam.gauss_curvature)]
    evidence = {
        "alpha": fam.alpha, "source": str(source), "kind": args.kind if args.mesh is None else None,
        "grid": grid, "input_reflected": fam.flipped, "load_density": fam.load_density, "loads": fam.loads,
        "phi": fam.phi, "r": fam.r, "K_phi": fam.gauss_curvature,
        "koenigs_tol": args.koenigs_tol, "koenigs_defect": R.dual.koenigs_defect, "dual_closure_residual": R.dual.closure_residual,
        "partner_vertex_spread": R.vertex_spread, "partner_polish_change": R.polish_change, "harmonic_residual": fam.harmonic_residual,
        "max_nonplanarity": {"phi": float(np.nanmax(face_nonplanarity(mesh_phi))),
                             "r": float(np.nanmax(face_nonplanarity(mesh_r))),
                             "network": float(np.nanmax(face_nonplanarity(net.mesh)))},
        "seconds": seconds,
        "conventions": "network z = -(phi + alpha r); weights = (q/2) creases of the convex Airy surface Phi; "
                       "loads = -q * reciprocal cell area (rule 'reciprocal') or -q * top-view area; "
                       "supports = boundary vertices, their loads = -q * top-view area; "
                       "K_phi = reciprocal cell area / top-view area",
    }
    tol = DEFAULT_CHECK_TOL if args.tol is None else args.tol
    status = built_status(net, tol)
    write_network_out(args.out, net, args.format, up=up, koebe=evidence, status=status, tol=tol,
                      max_relative_error=net.max_relative_error(), min_weight=net.min_weight())
    written = [args.out]
    for path, mesh in ((args.phi_out, mesh_phi), (args.partner_out, mesh_r), (args.network_out, net.mesh)):
        if path:
            write_mesh(path, mesh, up=up)
            written.append(path)
    label = os.path.basename(str(source))
    rows = [("Koebe mesh Φ", label + (" (a dome: reflected into Φ)" if fam.flipped else "")),
            ("vertices / faces / supports", f"{net.mesh.n_vertices} / {net.mesh.n_faces} / {int(net.supports.sum())}"),
            ("alpha", f"{fam.alpha:g}"),
            ("max relative error", f"{net.max_relative_error():.2e}"),
            ("min weight", f"{net.min_weight():.4g} N/m"),
            ("K_Φ = load / (q · top-view area)", f"{K.min():.4f} .. {K.max():.4f}" if K.size else "-"),
            ("Koenigs defect of Φ* (log ratio)", f"{R.dual.koenigs_defect:.1e}"),
            ("|Δφ r| / |Δφ φ| (R minimal)", f"{fam.harmonic_residual:.1e}"),
            ("max non-planarity Φ / R / network", "{phi:.1e} / {r:.1e} / {network:.1e}".format(
                **evidence["max_nonplanarity"])),
            ("time", f"{seconds:.3f} s"),
            ("written", ", ".join(written))]
    print_table("selfsupport koebe", rows)
    if status != "converged":
        # (rounded coordinates leave Φ's faces only nearly planar and its reciprocal cells only nearly
        # closed; top-view loads are exact only where K_Φ = 1; the heights' round-off grows with |α|)
        flat, defect = evidence["max_nonplanarity"]["phi"], R.dual.koenigs_defect
        why = []
        if max(flat, defect) > 1e-10:
            why.append(f"Φ's faces are planar to {flat:.1e} and its polar mesh has a Koenigs defect of {defect:.1e} "
                       "(rounded coordinates?)")
        if fam.loads == "top-view":
            why.append("top-view loads are exact only where K_Φ = 1 (use --kind inscribed or --loads reciprocal)")
        if not why or abs(fam.alpha) > 1:
            why.append(f"the heights' round-off grows with |α| (α = {fam.alpha:g}; try a smaller |--alpha|)")
        _err(not_in_equilibrium_line(net, tol, args.out, "; ".join(why) + "; or give a larger --tol"))
        return STATUS_EXIT[status]
    return EXIT_CODES["ok"]


COMMANDS: dict[str, Command] = {
    "koebe": Command("the self-supporting family Φ + αR of a Koebe mesh (paper §5, Fig. 15)",
                     add_koebe_arguments, run_koebe),
}
