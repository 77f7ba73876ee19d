"""``selfsupport stability`` and ``selfsupport destroy``: will the vault stand (paper §4)?

::

    selfsupport stability SCENE --thickness T [--load-at V[,V...]] [--loads 0,5000,10000,20000]
                          [--density RHO] [--method staggered|ipopt] --out DIR
                          [--max-load [--slide] | --max-horizontal DIRECTION | --thrust] [--time-limit S]
    selfsupport destroy SCENE --remove V [--remove V ...] --thickness T [--density RHO] --out DIR

``stability`` writes ``DIR/load-<kg>kg.json`` per added load (the network: certified, or the
closest one found) and ``DIR/stability.json`` (the table); with ``--max-load`` it solves the limit program
(:func:`selfsupport.structure.stability.max_load`, :mod:`selfsupport.structure.limit`), writes ``DIR/max-load.json``
(the certifying network) and ``DIR/max-load-program.json`` (the program's rounds, optimum and
binding vertices; with ``--slide``, the vertices also slide along the reference and the file lists
each round's certified load) and prints one line ``max load: N kg``. ``--max-horizontal DIRECTION``
(:func:`selfsupport.structure.limit.max_horizontal`) writes ``DIR/max-horizontal.json`` and
``DIR/max-horizontal-program.json`` and prints ``max horizontal acceleration: X g``; ``--thrust``
(:func:`selfsupport.structure.limit.thrust_range`) writes ``DIR/thrust-min.json``, ``DIR/thrust-max.json`` and
``DIR/thrust-program.json`` and prints ``thrust: min X kN, max Y kN``. ``destroy`` writes ``DIR/stage-<k>.json``
(network, original vertex ids, faces removed, stage status), ``DIR/destruction.json`` and
``DIR/stages.png``. Exit 0 when the runs completed (the verdicts are findings), 2 bad input,
4 when ``--max-load`` / ``--max-horizontal`` / ``--thrust`` certifies nothing (the verdict, on
stderr, says "locally infeasible" only when IPOPT reported it).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from selfsupport.api import make_method
from selfsupport.cli.common import (
    EXIT_CODES,
    Command,
    add_scene_arguments,
    load_scene,
    number_in,
    positive_float,
    positive_int,
    print_table,
)
from selfsupport.core.defaults import DEFAULT_DENSITY
from selfsupport.core.errors import InputError
from selfsupport.core.evidence import load_vectors, reaction_line
from selfsupport.core.loads import plan_direction
from selfsupport.figures.hull import stage_strip
from selfsupport.io import write_network
from selfsupport.io.atomic import atomic_write_text
from selfsupport.io.safety import check_output_dir
from selfsupport.structure.destruction import destroy
from selfsupport.structure.limit import LimitResult, max_horizontal, thrust_range
from selfsupport.structure.stability import max_load, stability_series

__all__ = ["COMMANDS", "parse_vertices", "parse_loads"]


def parse_vertices(text: str) -> list[int]:
    """``"3,17,20"`` -> ``[3, 17, 20]``."""
    try:
        out = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise InputError(f"--load-at {text!r}: give vertex indices separated by commas") from None
    if not out:
        raise InputError("--load-at needs at least one vertex index")
    return out


def parse_loads(text: str) -> list[float]:
    """``"0,5000,10000"`` -> masses in kg (finite, >= 0)."""
    try:
        out = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise InputError(f"--loads {text!r}: give masses in kg separated by commas") from None
    if not out or any(not (x >= 0 and x < float("inf")) for x in out):
        raise InputError(f"--loads {text!r}: give finite masses >= 0 kg")
    return out


def _method(name: str):
    return make_method(name)


def _kg_name(kg: float) -> str:
    return f"{kg:g}".replace("+", "")


# ------------------------------------------------------------------------------ stability
def _stability_args(p: argparse.ArgumentParser) -> None:
    add_scene_arguments(p)
    p.add_argument("--thickness", type=positive_float, required=True, metavar="T",
                   help="shell thickness [m]: the self-weight and the masonry hull (reference ± T/2)")
    p.add_argument("--density", type=positive_float, default=DEFAULT_DENSITY, metavar="RHO",
                   help=f"material density [kg/m^3] (default {DEFAULT_DENSITY:g})")
    p.add_argument("--load-at", default=None, metavar="V[,V...]",
                   help="vertices carrying the added mass, spread evenly (default: the scene's handled vertices)")
    p.add_argument("--loads", default="0,5000,10000,20000", metavar="KG[,KG...]",
                   help="added masses [kg] (default 0,5000,10000,20000)")
    limit = p.add_mutually_exclusive_group()
    limit.add_argument("--max-load", action="store_true",
                       help="instead, the largest added mass with a network inside the hull: one limit program (IPOPT), "
                            "certified by its network")
    limit.add_argument("--max-horizontal", default=None, metavar="DIRECTION",
                       help="instead, the largest horizontal acceleration a·g (each vertex's weight times a, along "
                            "DIRECTION: x, y, -x, -y or an angle in degrees from x) with a network inside the hull")
    limit.add_argument("--thrust", action="store_true",
                       help="instead, the least and greatest thrust (sum of the supports' horizontal reactions) of "
                            "networks inside the hull under self-weight")
    p.add_argument("--slide", action="store_true",
                   help="--max-load: the vertices also slide along the reference surface (rounds re-anchored at "
                        "the last certificate; the best certified round is the answer)")
    p.add_argument("--time-limit", type=positive_float, default=600.0, metavar="S",
                   help="--max-load, --max-horizontal, --thrust: wall-clock limit of the whole analysis [s] "
                        "(default 600)")
    p.add_argument("--method", choices=["staggered", "ipopt"], default="staggered",
                   help="staggered (no hull, then the hull as an active set) or ipopt (hard hull rows; warm-started from the "
                        "previous load)")
    p.add_argument("--out", "-o", required=True, metavar="DIR", help="output folder")


def _run_stability(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if args.slide and not args.max_load:
        raise InputError("--slide applies to --max-load only; add --max-load or drop --slide")
    loads = parse_loads(args.loads)
    at = parse_vertices(args.load_at) if args.load_at else None
    if args.max_horizontal is not None:
        plan_direction(args.max_horizontal)  # (a bad direction is refused before anything is solved)
        files = ["max-horizontal.json", "max-horizontal-program.json"]
    elif args.thrust:
        files = ["thrust-min.json", "thrust-max.json", "thrust-program.json"]
    else:
        files = (["max-load.json", "max-load-program.json"] if args.max_load
                 else [f"load-{_kg_name(k)}kg.json" for k in loads] + ["stability.json"])
    check_output_dir(out, files=files, inputs=[("scene", None if args.scene.startswith("shape:") else args.scene)])
    scene = load_scene(args.scene, supports=args.supports, up=args.up)
    method = _method(args.method)
    out.mkdir(parents=True, exist_ok=True)
    info = {"name": scene.name, "input": args.scene, "thickness": args.thickness, "density": args.density}
    if args.max_horizontal is not None:
        return _max_horizontal(scene, args, out, info)
    if args.thrust:
        return _thrust(scene, args, out, info)
    if args.max_load:
        m = max_load(scene, thickness=args.thickness, density=args.density, at=at, time_limit=args.time_limit,
                     slide=args.slide)
        r = m.limit
        atomic_write_text(out / "max-load-program.json", json.dumps(
            {"scene": info, **_program_record(r), "max_load_kg": r.value, "optimum_kg": r.optimum,
             **({"slide_rounds": list(r.slide)} if args.slide else {})}, indent=1,
            default=float) + "\n")
        if not r.certified:
            print(f"selfsupport: no max load: {r.message}", file=sys.stderr)
            return EXIT_CODES["not_converged"]
        write_network(out / "max-load.json", m.certificate, scene=info, added_mass_kg=m.kg,
                      program_optimum_kg=r.optimum)
        print_table(f"selfsupport stability --max-load -> {out}", [
            ("verdict", r.message),
            ("binding", ", ".join(f"{v} ({d:+.4f} t/2)" for v, d in r.binding[:8]) +
             (f", ... ({len(r.binding)} in all)" if len(r.binding) > 8 else "")),
            *([("sliding rounds", ", ".join(f"{x['round']}: " + ("-" if x["lambda_kg"] is None else
                                                                 f"{x['lambda_kg']:.6g} kg") for x in r.slide))]
              if args.slide else [])])
        print(f"max load: {m.kg:g} kg")
        return EXIT_CODES["ok"]
    steps = stability_series(scene, thickness=args.thickness, loads_kg=loads, density=args.density, at=at,
                             method=method)
    rows = []
    for s in steps:
        write_network(out / f"load-{_kg_name(s.kg)}kg.json", s.result, scene=info, added_mass_kg=s.kg,
                      load_at=list(s.at))
        rows.append(s.row())
    atomic_write_text(out / "stability.json", json.dumps({"scene": info, "load_at": list(steps[0].at) if steps else [],
                                                          "loads": rows}, indent=1, default=float) + "\n")
    print_table(f"selfsupport stability -> {out}", [
        (f"{r['added_kg']:g} kg", ("found inside the hull" if r["found"] else "NOT found") +
         f"; max rel. error {r['max_relative_error']:.1e}; max hull excess {r['max_hull_excess_m']:.3g} m "
         f"({r['outside']} outside the tolerance {r['hull_tolerance_m']:.2g} m); {r['seconds']:.1f} s") for r in rows])
    return EXIT_CODES["ok"]


def _program_record(r: LimitResult) -> dict:
    """What a limit program's ``*-program.json`` holds: the verdict, value, optimum, rounds and
    the binding vertices."""
    return {"kind": r.kind, "verdict": r.verdict, "value": r.value, "optimum": r.optimum,
            "ipopt_status": r.ipopt_status, "message": r.message, "rounds": list(r.rounds),
            "binding": [{"vertex": v, "distance_over_half_thickness": d} for v, d in r.binding]}


def _binding_text(r: LimitResult) -> str:
    return (", ".join(f"{v} ({d:+.4f} t/2)" for v, d in r.binding[:8]) +
            (f", ... ({len(r.binding)} in all)" if len(r.binding) > 8 else ""))


def _max_horizontal(scene, args: argparse.Namespace, out: Path, info: dict) -> int:
    """``--max-horizontal``: the limit program with λ the horizontal acceleration [g]."""
    d = plan_direction(args.max_horizontal)
    r = max_horizontal(scene, thickness=args.thickness, density=args.density, direction=args.max_horizontal,
                       time_limit=args.time_limit)
    info = {**info, "direction": args.max_horizontal, "direction_vector": d.tolist()}
    atomic_write_text(out / "max-horizontal-program.json", json.dumps(
        {"scene": info, **_program_record(r), "max_horizontal_acceleration_g": r.value}, indent=1,
        default=float) + "\n")
    if not r.certified:
        print(f"selfsupport: no max horizontal acceleration: {r.message}", file=sys.stderr)
        return EXIT_CODES["not_converged"]
    write_network(out / "max-horizontal.json", r.certificate, scene=info, horizontal_acceleration_g=r.value,
                  program_optimum_g=r.optimum)
    print_table(f"selfsupport stability --max-horizontal {args.max_horizontal} -> {out}", [
        ("verdict", r.message), ("binding", _binding_text(r)),
        ("support reactions", reaction_line(r.certificate.network.reaction_summary()))])
    print(f"max horizontal acceleration: {r.value:.6g} g")
    return EXIT_CODES["ok"]


def _thrust(scene, args: argparse.Namespace, out: Path, info: dict) -> int:
    """``--thrust``: the limit program with λ = 0, the thrust minimised and maximised."""
    lo, hi = thrust_range(scene, thickness=args.thickness, density=args.density, time_limit=args.time_limit)
    atomic_write_text(out / "thrust-program.json", json.dumps(
        {"scene": info, "min": _program_record(lo), "max": _program_record(hi),
         "thrust_min_N": lo.value, "thrust_max_N": hi.value}, indent=1, default=float) + "\n")
    for name, r in (("min", lo), ("max", hi)):
        if r.certified:
            write_network(out / f"thrust-{name}.json", r.certificate, scene=info, thrust_N=r.value)
    failed = [r for r in (lo, hi) if not r.certified]
    if failed:
        print(f"selfsupport: no thrust range: {'; '.join(f'{r.kind}: {r.message}' for r in failed)}", file=sys.stderr)
        return EXIT_CODES["not_converged"]
    print_table(f"selfsupport stability --thrust -> {out}", [
        ("min thrust", lo.message), ("max thrust", hi.message),
        ("total load", f"{-float(load_vectors(lo.certificate.network.loads)[:, 2].sum()) / 1e3:.6g} kN")])
    print(f"thrust: min {lo.value / 1e3:.6g} kN, max {hi.value / 1e3:.6g} kN")
    return EXIT_CODES["ok"]


# ------------------------------------------------------------------------------ destroy
def _destroy_args(p: argparse.ArgumentParser) -> None:
    add_scene_arguments(p)
    p.add_argument("--remove", action="append", type=number_in("[0, inf)", integer=True, what="a vertex index"),
                   required=True, metavar="VERTEX",
                   help="a vertex whose 1-ring of faces is removed; repeatable")
    p.add_argument("--thickness", type=positive_float, required=True, metavar="T", help="shell thickness [m]")
    p.add_argument("--density", type=positive_float, default=DEFAULT_DENSITY, metavar="RHO",
                   help=f"material density [kg/m^3] (default {DEFAULT_DENSITY:g})")
    p.add_argument("--max-stages", type=positive_int, default=20, metavar="N", help="stop after N stages (default 20)")
    p.add_argument("--no-figure", action="store_true", help="skip stages.png")
    p.add_argument("--out", "-o", required=True, metavar="DIR", help="output folder")


def _run_destroy(args: argparse.Namespace) -> int:
    out = Path(args.out)
    check_output_dir(out, files=["destruction.json", "stages.png"],
                     inputs=[("scene", None if args.scene.startswith("shape:") else args.scene)])
    scene = load_scene(args.scene, supports=args.supports, up=args.up)
    out.mkdir(parents=True, exist_ok=True)
    stages = destroy(scene, args.remove, thickness=args.thickness, density=args.density,
                     max_stages=args.max_stages)
    for s in stages:
        if s.result is not None:
            write_network(out / f"stage-{s.index}.json", s.result, stage=s.index, stage_status=s.status,
                          original_vertices=list(s.vertices), original_faces=list(s.faces),
                          faces_removed=list(s.removed), why_removed=s.why_removed)
    rows = [s.row() for s in stages]
    atomic_write_text(out / "destruction.json", json.dumps({"scene": args.scene, "remove": args.remove,
                                                            "thickness": args.thickness, "density": args.density,
                                                            "stages": rows}, indent=1, default=float) + "\n")
    if not args.no_figure:
        stage_strip(stages, out / "stages.png", thickness=args.thickness)
    print_table(f"selfsupport destroy -> {out}", [
        (f"stage {r['stage']}", f"{r['faces']} faces, {r['status']}; removed {r['removed']} ({r['why']})")
        for r in rows])
    return EXIT_CODES["ok"]


COMMANDS: dict[str, Command] = {
    "stability": Command("does a network inside the masonry hull carry added loads? (and the max load)",
                         _stability_args, _run_stability),
    "destroy": Command("remove vertices' 1-rings and find what still stands, stage by stage",
                       _destroy_args, _run_destroy),
}
