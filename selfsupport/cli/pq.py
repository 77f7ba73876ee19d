"""``selfsupport pq`` (picked up by :func:`selfsupport.cli.discover_commands`).

::

    selfsupport pq NET.json --out PQ.json [--spacing H] [--field principal|grid] [--angle DEG]
                   [--remesher seamless|streamlines|param] [--smoothing L] [--tol 1e-3] [--density RHO] [--thickness T]
                   [--method staggered|ipopt] [--no-finish] [--time-limit S]

Remeshes the network's top view along its relative principal directions
(:mod:`selfsupport.remesh.streamlines`: by default the integer iso-lines of a seamless integer-grid
parametrization of the smoothed field, :mod:`selfsupport.remesh.quadmesh`: quads, with irregular
vertices at the field's few singularities) and
solves the remeshed design with planar faces required (:class:`formulations.Planar`): a
network in equilibrium whose quads are planar to ``--tol`` (distance of the diagonals over the
mean edge length). ``--field grid`` remeshes along a fixed grid instead (the naive, unaligned
mesh of the paper's Fig. 12). ``--remesher streamlines`` draws evenly spaced streamlines
instead (triangles where a line ends), ``--remesher param`` the iso-lines of a parametrization
along the unsmoothed field. When the method does not
converge, the planar homotopy (and where that does not converge, IPOPT) finishes from the
network in equilibrium without planar faces (:func:`selfsupport.remesh.planar.solve_planar`;
``--no-finish``: not), and the homotopy's planar network is drawn toward the network's
reference surface. Prints the summary; exit codes as ``solve``.
"""
from __future__ import annotations

import argparse
import time

from selfsupport.cli.common import (
    EXIT_CODES,
    STATUS_EXIT,
    Command,
    _err,
    _not_converged_line,
    add_load_arguments,
    add_network_out_arguments,
    check_network_out,
    number_in,
    positive_float,
    print_table,
    summary_rows,
    tolerance,
    write_network_out,
)
from selfsupport.io.network_json import read_network
from selfsupport.remesh.planar import finish_summary, solve_planar
from selfsupport.remesh.quadmesh import SMOOTHING
from selfsupport.remesh.streamlines import FIELDS, METHODS, remesh

__all__ = ["COMMANDS", "add_pq_arguments", "run_pq"]


def add_pq_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``selfsupport pq``."""
    p.add_argument("network", metavar="NET.json", help="a network (selfsupport solve --out)")
    add_network_out_arguments(p, metavar="PQ.json", what="the planar-quad network")
    p.add_argument("--spacing", type=positive_float, default=None, metavar="H",
                   help="distance between neighbouring lines [m] (default: the network's mean top-view edge length)")
    p.add_argument("--field", choices=FIELDS, default="principal",
                   help="directions to follow: the relative principal directions, or a fixed grid (default principal)")
    p.add_argument("--remesher", choices=tuple(METHODS), default="seamless",
                   help="how the lines are drawn: the integer iso-lines of a seamless integer-grid parametrization "
                        "along the smoothed field (quads only but at its few singularities), evenly spaced streamlines "
                        "(T-junctions where a line ends), or the integer iso-lines of a parametrization along the "
                        "unsmoothed field (default seamless)")
    p.add_argument("--smoothing", type=positive_float, default=SMOOTHING, metavar="L",
                   help="--remesher seamless: the field's smoothing length over the top view's diagonal (larger: "
                        f"fewer singularities, less closely along the principal directions; default {SMOOTHING:g})")
    p.add_argument("--angle", type=number_in("[-360, 360]"), default=0.0, metavar="DEG", help="the grid's angle to the x axis (--field grid)")
    p.add_argument("--tol", type=tolerance, default=1e-3, metavar="TOL",
                   help="largest quad non-planarity accepted (default 1e-3)")
    p.add_argument("--method", choices=("staggered", "ipopt"), default="staggered", help="solver (default staggered)")
    p.add_argument("--no-finish", dest="finish", action="store_false",
                   help="no finish (planar homotopy, IPOPT) from the network in equilibrium without planar faces "
                        "when the method does not converge (selfsupport.remesh.planar)")
    p.add_argument("--time-limit", type=positive_float, default=None, metavar="S",
                   help="wall-clock limit of the command [s], the reading and the remesh included (default: the "
                        "method's); with the finish, the method gets a quarter of what is left and the finish the rest")
    add_load_arguments(p)


def run_pq(args: argparse.Namespace) -> int:
    """Remesh, solve with planar faces, write (see the module docstring)."""
    t0 = time.perf_counter()  # (--time-limit counts the reading and the remesh too)
    check_network_out(args.out, args.format, [("network", args.network)])
    net = read_network(args.network)
    q = remesh(net, spacing=args.spacing, field=args.field, angle=args.angle, method=args.remesher,
               smoothing=args.smoothing)
    left = None if args.time_limit is None else max(args.time_limit - (time.perf_counter() - t0), 1e-3)
    result = solve_planar(q.scene, tol=args.tol, method=args.method, finish=args.finish, time_limit=left,
                          density=args.density, thickness=args.thickness, reference=net.reference)
    planarity = result.parameters.get("planarity") or {}
    write_network_out(args.out, result, args.format, remesh={"field": q.field, "method": q.method, "spacing": q.spacing,
                                            "source": str(args.network), "face_sizes": q.face_size_counts,
                                            "irregular_vertices": q.irregular_vertices})
    rows = summary_rows(result, q.scene)
    rows += [("remesh", f"{q.field} ({q.method}), spacing {q.spacing:.4g} m, faces {q.face_size_counts}, "
                        f"{q.irregular_vertices} interior vertices of valence other than 4"),
             ("max non-planarity", f"{planarity.get('max_nonplanarity', float('nan')):.2e} (tol {args.tol:g})")]
    if result.parameters.get("planar_finish") is not None:
        rows.append(("finish", finish_summary(result)))
    print_table(f"selfsupport pq -> {args.out}", rows)
    if result.status != "converged":  # (one line on stderr, as for solve: what is wrong, what to do)
        limit = result.status in ("time_limit", "iteration_limit")  # (then the limit is what to change)
        short = ("" if planarity.get("met", True) else
                 f"the quads are not all planar (max non-planarity {planarity.get('max_nonplanarity', float('nan')):.2e}"
                 f" > tol {args.tol:g}{'' if limit else '; a larger --spacing or --tol, or another --field'}); ")
        _err(short + _not_converged_line(result))
    return STATUS_EXIT.get(result.status, EXIT_CODES["not_converged"])


COMMANDS: dict[str, Command] = {
    "pq": Command(help="remesh a network along its relative principal directions and solve it with planar faces",
                  add_arguments=add_pq_arguments, run=run_pq),
}
