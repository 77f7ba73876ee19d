"""``selfsupport edit`` (picked up by :func:`selfsupport.cli.discover_commands`).

::

    selfsupport edit SCRIPT.toml [--scene FILE|shape:NAME[:N]] [--up AXIS] [--supports FILE]
                     --out DIR [--force] [--cold] [--no-figures]

Replays an edit script (:mod:`selfsupport.design.script`): solves the starting scene, then
applies the edits in order with a warm re-solve after each stage, and writes
``DIR/stage-NN.json`` (the network format, with ``stage``: its index, edits and timings) and
``DIR/stage-NN.png`` (the network figure) per stage, and ``DIR/manifest.json`` naming the run:
the script, its SHA-256 and the stages in order with their files
(:class:`~selfsupport.io.runfolder.RunFolder`). Prints one line per stage.

DIR must be new or empty; ``--force`` replaces the files an earlier run wrote there (those its
manifest names, unchanged since) and keeps every other file.

Exit codes: 0 when every stage converged, 4 when some stage did not (its network is written
anyway), 2 bad input.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from selfsupport.cli.common import EXIT_CODES, Command, _err, load_scene, print_table
from selfsupport.core.errors import InputError
from selfsupport.design.script import EditScript, replay
from selfsupport.figures.render import FigureInput, render
from selfsupport.io import write_network
from selfsupport.io.runfolder import MANIFEST, RunFolder, file_sha256

__all__ = ["COMMANDS", "add_edit_arguments", "run_edit"]


def add_edit_arguments(p: argparse.ArgumentParser) -> None:
    """Arguments of ``selfsupport edit``."""
    p.add_argument("script", metavar="SCRIPT.toml", help="edit script (TOML; see selfsupport.design.script)")
    p.add_argument("--scene", default=None, metavar="FILE",
                   help="starting scene file or shape:NAME[:N] (replaces the script's [start] scene)")
    p.add_argument("--up", default=None, metavar="AXIS", help="the scene file's vertical axis (default: the format's)")
    p.add_argument("--supports", default=None, metavar="boundary|FILE", help="supports for files without pins")
    p.add_argument("--out", "-o", required=True, metavar="DIR",
                   help="new or empty folder for stage-NN.json, stage-NN.png and manifest.json")
    p.add_argument("--force", action="store_true",
                   help="write into a folder that is not empty: the files an earlier run wrote there (named by its "
                        "manifest.json) are replaced; any other file is kept")
    p.add_argument("--cold", action="store_true", help="solve every stage from scratch (no warm start)")
    p.add_argument("--no-figures", action="store_true", help="write the networks only")


def run_edit(args: argparse.Namespace) -> int:
    """Replay the script and write every stage (see the module docstring)."""
    script = EditScript.read(args.script)
    scene = None
    if args.scene is not None or args.supports is not None or args.up is not None:
        spec = args.scene if args.scene is not None else script.scene
        if spec is None:
            raise InputError("--supports/--up need a scene (--scene or the script's [start] scene)")
        scene = load_scene(spec, supports=args.supports, up=args.up)
    out = Path(args.out)
    n_stages = 1 + sum(script.solve_after) + (1 if script.solve_after and not script.solve_after[-1] else 0)
    exts = ("json",) if args.no_figures else ("json", "png")
    names = [f"stage-{k:02d}.{ext}" for k in range(n_stages) for ext in exts]
    ins = [("script", args.script)] + ([("scene", args.scene)] if args.scene and not args.scene.startswith("shape:")
                                       else [])
    folder = RunFolder.prepare(out, names, force=args.force, inputs=ins,
                               info={"command": "edit", "script": os.path.abspath(args.script),
                                     "script_sha256": file_sha256(args.script)})
    if folder.leftovers:
        shown = ", ".join(folder.leftovers[:5]) + (", ..." if len(folder.leftovers) > 5 else "")
        _err(f"warning: {out} also holds files this run did not write ({shown}); they were kept and are not "
             f"part of it (see {MANIFEST})")
    rows: list[tuple[str, str]] = []
    worst = "converged"

    def write(stage) -> None:
        nonlocal worst
        res = stage.result
        base = out / f"stage-{stage.index:02d}"
        info = {"index": stage.index, "edits": [e.to_dict() for e in stage.edits], "warm": stage.warm,
                "edit_seconds": stage.edit_seconds, "density": stage.design.density,
                "thickness": stage.design.thickness, "w_max": stage.design.w_max}
        write_network(base.with_suffix(".json"), res, stage=info)
        written = [base.with_suffix(".json").name]
        if not args.no_figures:
            ops = "+".join(e.op for e in stage.edits) or "start"
            render("network", FigureInput(res.network, title=f"stage {stage.index:02d}: {ops} "
                                                              f"({res.status}, {res.max_relative_error:.1e})"),
                   base.with_suffix(".png"))
            written.append(base.with_suffix(".png").name)
        folder.record({"index": stage.index, "edits": [e.op for e in stage.edits], "status": res.status}, written)
        if res.status != "converged":
            worst = res.status
        ops = "+".join(e.op for e in stage.edits) or "start"
        rows.append((f"stage {stage.index:02d} {ops}",
                     f"{res.status}, {res.iterations} it, {res.wall_time:.2f} s"
                     f"{' (warm)' if (res.parameters.get('warm_start') or {}).get('used') else ''}, "
                     f"{res.network.mesh.n_vertices} V, max rel. error {res.max_relative_error:.2e}"))

    t0 = time.perf_counter()
    replay(script, scene, on_stage=write, warm=False if args.cold else None)
    folder.finish()
    rows.append(("total", f"{time.perf_counter() - t0:.2f} s"))
    print_table(f"edit {args.script} -> {out}", rows)
    return EXIT_CODES["ok"] if worst == "converged" else EXIT_CODES["not_converged"]


COMMANDS: dict[str, Command] = {
    "edit": Command(help="replay a design edit script (TOML) with a warm re-solve after each stage",
                    add_arguments=add_edit_arguments, run=run_edit),
}
