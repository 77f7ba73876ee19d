"""The ``selfsupport`` command line.

::

    selfsupport solve SCENE --out NET.json [--method auto|staggered|multilevel|ipopt|nlopt] [...]
    selfsupport check MESH_OR_NET [--supports ...] [--tol 1e-6] [--out NET.json]
    selfsupport demo [--out DIR] [--shape NAME] [--vertices N]

``SCENE`` is a file (``.sss``, ``.obj``, ``.ply``, ``.off``, ``.json``) or a built-in shape
written ``shape:NAME`` or ``shape:NAME:VERTICES`` (e.g. ``shape:pillar_vault:500``).

Exit codes (:data:`EXIT_CODES`): 0 success (converged / self-supporting); 1 ``check`` found the
surface is not self-supporting, or an unexpected internal error; 2 bad input or usage;
3 solver backend unavailable; 4 no network in equilibrium (stalled, infeasible, failed);
5 iteration or time limit reached; 130 interrupted (Ctrl-C or SIGTERM, which stops a run as
Ctrl-C does: files being written are cleaned up). Every error is one line on
stderr, ``selfsupport: error: ...``; ``--debug`` shows the traceback instead.

Adding a subcommand
-------------------
Subcommands live in :data:`COMMANDS` (name -> :class:`Command`). Another module adds its own
without touching this file: create ``selfsupport/cli/<anything>.py`` defining a module-level
``COMMANDS: dict[str, Command]``, a dict literal whose entries are written
``"name": Command("one-line help", add_arguments, run)``. The top-level parser lists the commands
from :func:`command_index`, which reads these declarations from the modules' source without
importing them; only the chosen command's module is imported (:func:`load_command`), so a command
module may import its layer at the top. Return an exit code from ``run``, raise
:class:`~selfsupport.core.errors.SelfSupportError` subclasses for errors the user can fix.
Helpers for them: :func:`add_scene_arguments`, :func:`add_load_arguments`, :func:`load_scene`,
:func:`stdout_console`, :func:`print_table`, :func:`summary_rows`, for a network ``--out``
:func:`add_network_out_arguments`, :func:`check_network_out`, :func:`write_network_out`, and the argparse types
:func:`number_in` (a finite number in an interval), :func:`positive_float`, :func:`positive_int`,
:data:`tolerance`.
"""
from __future__ import annotations

import argparse
import ast
import atexit
import contextlib
import gc
import importlib
import json
import math
import os
import pkgutil
import re
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Collection, Iterator, NoReturn, Sequence

from selfsupport import __version__
from selfsupport.core.defaults import DEFAULT_CHECK_TOL, DEFAULT_DENSITY, DEFAULT_THICKNESS
from selfsupport.core.errors import InputError, SelfSupportError
from selfsupport.methods import METHODS, capabilities, find_method

__all__ = ["Command", "COMMANDS", "EXIT_CODES", "STATUS_EXIT", "CommandEntry", "command_index", "declared_commands",
           "load_command", "discover_commands", "build_parser", "main", "console_main",
           "add_scene_arguments", "add_load_arguments", "load_scene", "stdout_console", "print_table",
           "number_in", "positive_float", "positive_int", "tolerance", "summary_rows", "sigterm_interrupts",
           "add_network_out_arguments", "check_network_out", "write_network_out"]

PROG = "selfsupport"

#: Exit codes of the command line.
EXIT_CODES: dict[str, int] = {
    "ok": 0,
    "not_self_supporting": 1,
    "internal": 1,
    "input": 2,
    "backend": 3,
    "not_converged": 4,
    "limit": 5,
    "interrupted": 130,
}

#: Solve status -> exit code. The network is written whatever the status (its ``status`` key says it).
STATUS_EXIT: dict[str, int] = {
    "converged": EXIT_CODES["ok"],
    "stalled": EXIT_CODES["not_converged"],
    "infeasible": EXIT_CODES["not_converged"],
    "failed": EXIT_CODES["not_converged"],
    "iteration_limit": EXIT_CODES["limit"],
    "time_limit": EXIT_CODES["limit"],
    "interrupted": EXIT_CODES["interrupted"],
}

#: Solve status -> what to try next (printed when the result is not in equilibrium).
STATUS_HINT: dict[str, str] = {
    "stalled": "try --method ipopt, more or other supports (--supports), a larger --wmax, or a smoother reference",
    "infeasible": "no compressive network exists near this shape with these supports and bounds; "
                  "add supports, raise --wmax or change the shape",
    "failed": "try the other method (--method staggered / --method ipopt) or a smoother reference",
    "iteration_limit": "raise --max-iter (or --time-limit), or try --method ipopt",
    "time_limit": "raise --time-limit, try --method multilevel for a big mesh, or try the other method",
    "interrupted": "rerun and let it finish",
}
#: The hint of an "infeasible" hull search (``--hull``): its search is a heuristic, so not finding a
#: network inside the hull proves nothing (see selfsupport.structure.stability).
HULL_HINT = ("not finding a network inside the hull is no proof of collapse; try a larger --thickness or more "
             "supports, or --method ipopt")
#: Above this many vertices a hint does not suggest IPOPT: its simultaneous solve runs out of time
#: on the paper's larger scenes (docs/guide/methods.md).
IPOPT_HINT_MAX = 2000
#: How each hint's IPOPT alternative is struck out for a mesh above IPOPT_HINT_MAX.
_NO_IPOPT = (("try --method ipopt, ", "try "), (", or try --method ipopt", ""), (", or --method ipopt", ""),
             (" / --method ipopt", ""))


# --------------------------------------------------------------------------- registry
@dataclass(frozen=True)
class Command:
    """A subcommand: its one-line help, an argument adder and a runner returning the exit code."""

    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


class _UsageError(Exception):
    """argparse's complaints, turned into our one-line error."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        raise _UsageError(f"{message} (see '{self.prog} --help')")


# ---------------------------------------------------------------------- shared helpers
def number_in(interval: str, *, integer: bool = False, what: str | None = None) -> Callable[[str], Any]:
    """argparse ``type=``: a finite number (an integer with ``integer``) inside ``interval``.

    ``interval`` is written as in :mod:`selfsupport.core.options` (``"(0, 1]"``, ``"[1, inf)"``); NaN and
    infinities are refused, and the message states the interval (``what`` names the kind of value).

    >>> number_in("(0, 1]")("0.5")
    0.5
    >>> number_in("(0, 1]")("100")
    Traceback (most recent call last):
    ...
    argparse.ArgumentTypeError: '100' is out of range; give a finite number in (0, 1]
    """
    from selfsupport.core.options import in_interval

    kind = "an integer" if integer else "a finite number"

    def parse(text: str) -> Any:
        try:
            x = int(text) if integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if integer else 'a number'}; "
                                             f"give {kind} in {interval}") from None
        # (an int compares with the interval's float ends exactly; only a float can be NaN or infinite)
        if not ((integer or math.isfinite(x)) and in_interval(x, interval)):
            head = f"must be {what}" if what else "is out of range"
            raise argparse.ArgumentTypeError(f"{text!r} {head}; give {kind} in {interval}")
        return x

    parse.__name__ = "integer" if integer else "number"  # (argparse names the type in some messages)
    return parse


positive_float = number_in("(0, inf)", what="a positive finite number")
positive_float.__doc__ = "argparse ``type=``: a positive finite float."
positive_int = number_in("[1, inf)", integer=True, what="at least 1")
positive_int.__doc__ = "argparse ``type=``: an integer >= 1."
#: argparse ``type=`` of a relative tolerance (a relative error of 1 is already the size of the
#: quantity itself, so a larger one would accept anything)
tolerance = number_in("(0, 1]", what="a relative tolerance of at most 1")


# the underscore names were used by the first plugin modules; keep them working
_positive_float, _positive_int = positive_float, positive_int


def add_scene_arguments(p: argparse.ArgumentParser, *, metavar: str = "SCENE") -> None:
    """``SCENE`` (file or ``shape:NAME[:VERTICES]``), ``--supports``, ``--up``."""
    p.add_argument("scene", metavar=metavar,
                   help="scene or mesh file (.sss .obj .ply .off .json), or a built-in shape "
                        "'shape:NAME[:VERTICES]' (e.g. shape:pillar_vault:500)")
    p.add_argument("--supports", metavar="boundary|FILE", default=None,
                   help="supported vertices for files without pins: 'boundary' or a file of 0-based "
                        "vertex indices ('#' comments); replaces the file's own pins if given")
    p.add_argument("--up", default=None, metavar="AXIS",
                   help="the file's vertical axis: z, -z, y, -y, x, -x (default: z; .sss files and the "
                        "paper's OBJ files are -y)")


def add_load_arguments(p: argparse.ArgumentParser, *, default: bool = True) -> None:
    """``--density`` and ``--thickness`` (self-weight ρ·t·g per unit area)."""
    p.add_argument("--density", type=positive_float, default=DEFAULT_DENSITY if default else None,
                   metavar="RHO", help=f"material density [kg/m^3] (default {DEFAULT_DENSITY:g})")
    p.add_argument("--thickness", type=positive_float, default=DEFAULT_THICKNESS if default else None,
                   metavar="T", help=f"shell thickness [m] (default {DEFAULT_THICKNESS:g})")


def load_scene(spec: str, *, supports: str | None = None, up: str | None = None):
    """A :class:`~selfsupport.core.scene.Scene` from a ``SCENE`` argument (file or ``shape:NAME[:N]``;
    :func:`selfsupport.io.scenes.load_scene`)."""
    from selfsupport.io import scenes

    return scenes.load_scene(spec, supports=supports, up=up)


def stdout_console():
    """A rich console on the *current* ``sys.stdout`` (so pytest's capture sees it)."""
    from rich.console import Console

    return Console(file=sys.stdout, highlight=False, soft_wrap=True)


def _console_width() -> int:
    """The width rich gives a console off a terminal: ``COLUMNS`` when it is a number, else the
    size of the first terminal among stdin, stdout and stderr, else 80."""
    width = 0
    for fd in (0, 1, 2):
        try:
            width = os.get_terminal_size(fd).columns
        except (AttributeError, ValueError, OSError):
            continue
        break
    columns = os.environ.get("COLUMNS", "")
    return int(columns) if columns.isdigit() else (width or 80)


_RICH_WORD = re.compile(r"\s*\S+\s*")
# text rich would read as markup ("[bold]") or an emoji code (":smile:"), or whose cell widths are not its length
_RICH_SPECIAL = re.compile(r"\[[a-zA-Z#/@]|:\S+:|[^\n\x20-\x7e]")


def _wrap_words(line: str, width: int) -> list[str] | None:
    """``line`` broken as rich breaks a table cell's text ``width`` wide (greedy, at the start of a
    word, a word's trailing spaces allowed past the edge); None when a word is longer than ``width``
    (rich crops it with an ellipsis)."""
    pieces, start, offset, pos = [], 0, 0, 0
    while (m := _RICH_WORD.match(line, pos)) is not None:
        word, pos = m.group(0), m.end()
        length = len(word.rstrip())
        if length > width:
            return None
        if width - offset >= length:
            offset += len(word)
        elif offset and m.start():
            pieces.append(line[start:m.start()])
            start, offset = m.start(), len(word)
    return [*pieces, line[start:]]


def plain_table(title: str, rows: Sequence[tuple[str, str]], width: int) -> str | None:
    """The text of :func:`print_table`'s rich table off a terminal ``width`` columns wide, without
    rich (~0.04 CPU s of a command's start to import and lay out): the title's line, then each
    row's key padded to the widest key, two spaces, its value; when the table is wider than
    ``width``, the wider column is wrapped at words to what is left. None for what only rich lays
    out (markup, emoji codes, text other than printable ASCII, a word wider than its column, two
    columns that must both shrink, no rows)."""
    cells = [(str(k), str(v)) for k, v in rows]
    if not cells or any(_RICH_SPECIAL.search(t) for t in (title, *(c for row in cells for c in row))):
        return None
    widths = [min(max(len(line) for c in cells for line in c[i].split("\n")) + 1, width) for i in (0, 1)]
    excess = sum(widths) - width
    if excess > 0:  # (rich narrows the widest column, at most down to the other's width)
        i = int(widths[1] >= widths[0])
        if widths[i] - widths[1 - i] < excess:
            return None
        widths[i] -= excess
    out = [line.rstrip() for line in title.split("\n")] if title else []
    for key, value in cells:
        parts = []
        for cell, w in zip((key, value), widths):
            wrapped = [_wrap_words(line, w - 1) for line in cell.split("\n")]
            if any(lines is None for lines in wrapped):
                return None
            parts.append([p.rstrip() for lines in wrapped for p in lines])
        for j in range(max(map(len, parts))):
            k = parts[0][j] if j < len(parts[0]) else ""
            v = parts[1][j] if j < len(parts[1]) else ""
            out.append((k.ljust(widths[0] - 1) + "  " + v).rstrip())
    return "".join(line + "\n" for line in out)


def print_table(title: str, rows: Sequence[tuple[str, str]]) -> None:
    """A two-column summary table on stdout (no trailing spaces on its lines); off a terminal laid
    out by :func:`plain_table` where it can, to the same text."""
    from selfsupport.core.progress import may_be_terminal

    if not may_be_terminal(sys.stdout):
        text = plain_table(title, rows, _console_width())
        if text is not None:
            sys.stdout.write(text)
            return
    from rich.table import Table

    t = Table(title=title, show_header=False, title_justify="left", box=None, pad_edge=False)
    t.add_column(style="bold")
    t.add_column()
    for k, v in rows:
        t.add_row(k, v)
    console = stdout_console()
    with console.capture() as cap:
        console.print(t)
    # rich pads every cell to its column's width; the padding of the last column is noise
    sys.stdout.write("".join(line.rstrip() + "\n" for line in cap.get().splitlines()))


def _err(message: str) -> None:
    print(f"{PROG}: {message}", file=sys.stderr)


def scene_inputs(args: argparse.Namespace) -> list[tuple[str, str | None]]:
    """The input files named by :func:`add_scene_arguments` (for
    :func:`selfsupport.io.safety.check_outputs`: no output may be one of them)."""
    scene = None if args.scene.startswith("shape:") else args.scene
    sup = getattr(args, "supports", None)
    return [("scene", scene), ("--supports file", None if sup in (None, "boundary") else sup)]


def report_files() -> list[str]:
    """The files ``--report DIR`` writes into DIR."""
    from selfsupport.figures.report import REPORT_KINDS

    return [f"{k}.png" for k in REPORT_KINDS] + ["view.html"]


def print_warnings(result, scene) -> None:
    """One stderr line per warning of :func:`selfsupport.methods.diagnostics.solve_warnings` (input
    issues, a network far from its reference, one that leaves the masonry hull)."""
    from selfsupport.methods.diagnostics import solve_warnings

    for line in solve_warnings(result, scene):
        _err(f"warning: {line}")


def summary_rows(result, scene) -> list[tuple[str, str]]:
    """Rows of the summary table of a solve."""
    from selfsupport.core import evidence
    from selfsupport.core.geometry import bbox_diagonal

    net = result.network
    diag = bbox_diagonal(scene.mesh.vertices)
    rows = [("scene", scene.name), ("vertices", str(net.mesh.n_vertices)),
            ("edges", f"{net.mesh.n_edges} ({int(net.active_edges.sum())} carrying a weight)"),
            ("supports", str(int(net.supports.sum()))),
            ("method", _method_text(result)), ("backend", result.backend), ("status", result.status),
            ("iterations", str(result.iterations)), ("time", f"{result.wall_time:.2f} s"),
            ("max relative error", f"{result.max_relative_error:.3e}"),
            ("min weight", f"{result.min_weight:.4g} N/m"),
            *tension_rows(result),
            ("total load", f"{float(net.loads.sum()):.6g} N"),
            ("support reactions", evidence.reaction_line(net.reaction_summary())),
            ("distance to reference mean", f"{result.distance_mean:.3e} of bbox diagonal "
                                           f"({result.distance_mean * diag:.3g} m)"),
            ("distance to reference max", f"{result.distance_max:.3e} of bbox diagonal "
                                          f"({result.distance_max * diag:.3g} m)")]
    split = result.parameters.get("triangulated")
    if split:
        rows.append(("triangulated", f"{split['faces']} faces -> {split['triangles']} triangles, {split['edges']} -> "
                                     f"{split['edges_after']} edges ({split['rule']})"))
    design = result.parameters.get("design")
    if design and "start" in design:  # a re-solved network file or a warm start: what the solve was for
        # and began at (a warm start on a plain scene has no stored reference: the pq finish on a turned vault)
        rows += [(key, design[key]) for key in ("reference", "start") if key in design]
    for name, value in result.terms.items():  # the objective, term by term (SI units: m²)
        rows.append((f"objective {name}", f"{value:.4g} m^2"))
    for name, case in result.cases:
        rows.append((f"load case {name}", f"max relative error {case.max_relative_error():.3e}, "
                                          f"total load {float(case.loads.sum()):.6g} N"))
    blocked = peel_line(result)
    if blocked:
        rows.append(("load cases", blocked))
    hull = result.parameters.get("hull")
    if hull:
        from selfsupport.methods.hull_search import stands_line

        rows.append(("masonry hull", f"t = {hull['thickness']:g} m: {hull['outside']} free vertices outside "
                                     f"(max excess {hull['max_excess']:.3g} m)"))
        rows.append(("verdict", stands_line(result.parameters)))
    return rows


#: What to change where the peel blocks a case: the mesh, not the method or its settings.
PEEL_HINT = "split the quads into triangles (--triangulate), or support the free edges"


def peel_line(result) -> str | None:
    """The peel's verdict of a stalled solve over several cases (``any_weights_carry``'s ``peel``,
    :mod:`formulations.peel`) in a line, where it blocks a case; else None."""
    for name, c in (result.parameters.get("any_weights_carry") or {}).items():
        at = (c.get("peel") or {}).get("blocked_at")
        if at:
            return (f"case {name!r} shares a geometry with case {c['from']!r} on this mesh only at a degenerate "
                    f"vertex star (the peel from the free edges reaches vertex {at[0]}): {PEEL_HINT}")
    return None


def tension_rows(result) -> list[tuple[str, str]]:
    """The summary row of the edges in tension, when the solve allowed tension or found some."""
    t = result.parameters.get("tension")
    if t is None:
        return []
    return [("tension edges", f"{t['edges']} (most negative weight {t['min_weight']:.4g} N/m)")]


def _method_text(result) -> str:
    """The summary's method: its name, and with ``--method auto`` why it was chosen."""
    choice = result.parameters.get("method_choice")
    return f"{result.method} (auto: {choice['why']})" if choice else result.method


def _not_converged_line(result) -> str:
    """One line for a solve that did not converge, true to what was written.

    A run stopped early (iteration or time limit) is still polished: weights frozen, positions
    solved exactly. Its network can then be in equilibrium, only not the one nearest to the
    reference, so the line says which of the two cases it is.
    """
    # (a network held above tol by rounding alone: its message says what to change, the status's
    # usual hint — other methods, more supports — would not help)
    in_hull = result.status == "infeasible" and bool(result.parameters.get("hull"))
    hint = ("see the message for what to change" if result.parameters.get("roundoff_limit")
            else HULL_HINT if in_hull else STATUS_HINT.get(result.status, "try the other method"))
    n = result.network.mesh.n_vertices
    # (not after --method auto: it chose one level because no coarser level could carry the problem)
    caps = capabilities(result.method) if result.method in METHODS else None
    one_level = caps is not None and not caps.levels and not caps.simultaneous
    if (result.status == "stalled" and one_level and hint == STATUS_HINT["stalled"]
            and "method_choice" not in result.parameters):
        from selfsupport.methods.multilevel import DIRECT_MAX

        if n > DIRECT_MAX:
            # (a single level can stall far from equilibrium at this size where the levels converge)
            hint = (f"try --method {find_method(levels=True)} (a mesh this large, e.g. a subdivided design); "
                    f"otherwise {hint}")
    if peel_line(result):  # (the mesh rules out every network without a degenerate star)
        hint = f"this mesh carries these load cases only at a degenerate vertex star: {PEEL_HINT}"
    elif caps is not None and caps.simultaneous:  # (IPOPT or nlopt ran already: the other one to try is staggered)
        hint = hint.replace("--method ipopt", "--method staggered")
    elif n > IPOPT_HINT_MAX:
        for phrase, instead in _NO_IPOPT:
            hint = hint.replace(phrase, instead)
    msg = f" ({result.message})" if result.message else ""
    tol = float(result.parameters.get("tol", 1e-9) or 1e-9)
    if result.max_relative_error <= tol:
        short = ("is not inside the masonry hull" if in_hull else
                 f"is not the solution nearest to the reference (mean distance {result.distance_mean:.2e} of the "
                 "bbox diagonal)")
        return (f"did NOT converge: status {result.status}{msg}; the written network is in equilibrium "
                f"(max relative error {result.max_relative_error:.2e}) but {short}; {hint}")
    return (f"the network is NOT in equilibrium: status {result.status}{msg}, max relative error "
            f"{result.max_relative_error:.2e} > {tol:g}; {hint}")


def network_out_help(what: str = "network file to write") -> str:
    """The help of a network ``--out``: the formats of :data:`selfsupport.io.NETWORK_FORMATS`."""
    from selfsupport.io import NETWORK_FORMATS

    return f"{what}: " + "; ".join(f"{s} {f.summary}" for s, f in NETWORK_FORMATS.items())


def add_network_out_arguments(p: argparse.ArgumentParser, *, metavar: str = "NET.json", required: bool = True,
                              what: str = "network file to write") -> None:
    """``--out`` (a network file, in the format its suffix names) and ``--format``."""
    from selfsupport.io import FORMAT_NAMES

    p.add_argument("--out", "-o", required=required, default=None, metavar=metavar, help=network_out_help(what))
    p.add_argument("--format", choices=list(FORMAT_NAMES), default=None,
                   help="the --out format when its suffix does not say it (compas: a COMPAS mesh in a .json file)")


def check_network_out(out: str | Path, fmt: str | None = None,
                      inputs: Sequence[tuple[str, str | Path | None]] = ()) -> None:
    """Check a network ``--out`` before any work: the file (the rules of
    :mod:`selfsupport.io.safety`), then its format (``fmt`` or its suffix: one no writer has is
    refused), then the side files that format writes beside it."""
    from selfsupport.io import network_outputs
    from selfsupport.io.safety import check_outputs

    check_outputs([("--out", out)], inputs)
    check_outputs([("--out side file", f) for f in network_outputs(out, fmt)[1:]], inputs)


def write_network_out(out: str | Path, result_or_network, fmt: str | None = None, **extra: Any) -> None:
    """Write ``--out`` in the format ``fmt`` or its suffix names
    (:func:`selfsupport.io.write_network_as`); a format that does not hold everything says in one
    stderr line where the rest is (side files) and what is left out."""
    from selfsupport.io import network_note, write_network_as

    write_network_as(out, result_or_network, fmt=fmt, **extra)
    note = network_note(out, fmt)
    if note:
        _err(f"note: {note}")


def built_status(network, tol: float) -> str:
    """The ``status`` written with a network that is built rather than solved (``koebe``,
    ``construct``): ``"converged"`` when it is in equilibrium to ``tol``
    (:meth:`~selfsupport.core.result.Network.in_equilibrium`), else ``"failed"``; exit codes as
    :data:`STATUS_EXIT`."""
    return "converged" if network.in_equilibrium(tol) else "failed"


def not_in_equilibrium_line(network, tol: float, path: str, hint: str) -> str:
    """The stderr line of a built network that is not in equilibrium (see :func:`built_status`)."""
    return (f"the network written to {path} is NOT in equilibrium: max relative error "
            f"{network.max_relative_error():.2e} > tol {tol:g} (its status is 'failed'); {hint}")


# ----------------------------------------------------------------------------- solve
def _solve_args(p: argparse.ArgumentParser) -> None:
    from selfsupport.api import AUTO, METHODS

    add_scene_arguments(p)
    # what a network file means as input (api.design_of): said here, where a user re-solving looks
    p.epilog = ("A network file (.json) written by 'solve' is solved for the reference it stores "
                "(reference_vertices), starting from the stored network and its weights (staggered, ipopt; "
                "nlopt and the staggered --hull search start from the reference); its reference_vertices "
                "are written unchanged. A file without a stored reference is its own reference.")
    add_network_out_arguments(p)
    p.add_argument("--method", choices=[AUTO, *METHODS], default=AUTO,
                   help="solution method (default auto: multilevel on a mesh large enough for coarser levels "
                        "to pay, else staggered; the summary says which and why)")
    p.add_argument("--subdivide", type=positive_int, default=None, metavar="K",
                   help="refine the design by K Catmull-Clark steps first (quads; supports kept along "
                        "creases), e.g. to fabrication resolution; the multilevel method (which auto picks for a "
                        "mesh large enough) then solves the design and each step in turn, each from the one before")
    p.add_argument("--triangulate", action="store_true",
                   help="split every face into triangles first, along its shortest diagonals (quads: the shorter "
                        "one; after --subdivide): more edges than a quad mesh's, which several load cases on a design "
                        "with free edges need; supports and loads stay on the same vertices, bounds from --bounds "
                        "stay on the kept edges and the new diagonals take the defaults")
    p.add_argument("--backend", default=None, metavar="NAME",
                   help="inner solver where the method has a choice (staggered: its Step-2 weight fit, "
                        "one of selfsupport.methods.weightfit_backends.WEIGHT_FIT_BACKENDS, default active-set)")
    add_load_arguments(p)
    p.add_argument("--wmax", type=positive_float, default=None, metavar="W", help="upper weight bound [N/m]")
    p.add_argument("--eps", "--w-min", type=number_in("(-inf, inf)"), default=None, metavar="E", dest="eps",
                   help="lower weight bound [N/m] (default: scale-free, 1e-4 of the natural weight scale); "
                        "0 or negative lets the edges take tension down to it (steel, glass)")
    p.add_argument("--max-stress", type=positive_float, default=None, metavar="MPA",
                   help="allowable stress [MPa]: w_max per edge = stress x thickness x the edge's tributary "
                        "width / its length (instead of --wmax)")
    p.add_argument("--bounds", metavar="FILE", default=None,
                   help="per-edge bounds over --eps/--wmax/--max-stress: a CSV of i,j,w_min,w_max rows [N/m] "
                        "(edges by their vertex pair, an empty bound keeps the default) or a JSON with edges "
                        "and w_min / w_max arrays in their order")
    p.add_argument("--tol", type=tolerance, default=None,
                   help="required max relative error, in (0, 1] (default: the method's, 1e-9)")
    p.add_argument("--max-iter", type=positive_int, default=None, metavar="N",
                   help="iteration limit (staggered: outer iterations, default 200; ipopt: per load round)")
    p.add_argument("--time-limit", type=positive_float, default=None, metavar="S",
                   help="wall-clock limit in seconds (default: the method's, 600 s staggered / 120 s ipopt)")
    p.add_argument("--max-memory", type=positive_float, default=None, metavar="GIB",
                   help="memory the solve may use, in GiB (default: what the machine has available); a mesh "
                        "estimated to need more is refused before any work")
    p.add_argument("--report", metavar="DIR", default=None,
                   help="also write the figures (network, deviation, airy, reciprocal, directions, history) and view.html into DIR")
    p.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                   help="a staggered-method setting, repeatable (e.g. coupled=true, shrink=0.5; "
                        "see StaggeredOptions)")
    add_problem_arguments(p)
    p.add_argument("--keep-partial", action="store_true",
                   help="on Ctrl-C write the interrupted network to --out itself; by default it goes to "
                        "NAME.interrupted.json next to it and an existing --out file is never replaced")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress display")


def add_problem_arguments(p: argparse.ArgumentParser) -> None:
    """The rest of the problem: objective terms, extra loads, load cases, constraints."""
    from formulations import TERMS

    p.add_argument("--objective", action="append", default=[], metavar="NAME=WEIGHT",
                   help="an objective term and its weight, repeatable; NAME one of "
                        f"{', '.join(sorted(TERMS))} (default: the method's own objective: staggered "
                        "reference=1, ipopt vertices=1)")
    p.add_argument("--point-load", action="append", default=[], metavar="VERTEX:NEWTONS",
                   help="a load on a vertex in N, positive downward (V:5000 hangs 5 kN), on every load case; "
                        "repeatable")
    p.add_argument("--extra-mass", action="append", default=[], metavar="VERTEX:KG",
                   help="extra mass on a vertex in kg, on every load case; repeatable")
    p.add_argument("--load-cases", metavar="FILE", default=None,
                   help="TOML file of named load cases ([cases.NAME] with self_weight, uniform_mass [kg/m^2], "
                        "point_loads, extra_mass); one geometry must stand under every case, with one weight "
                        "vector each")
    p.add_argument("--hull", action="store_true",
                   help="keep every free vertex within +-thickness/2 of the reference (the masonry hull)")
    p.add_argument("--fixed-top-view", action="store_true",
                   help="keep x and y of the free vertices: only the heights move (thrust network analysis)")
    p.add_argument("--planar", nargs="?", const=1e-3, default=None, type=tolerance, metavar="TOL",
                   help="planar faces (glass or steel panels): every quad's diagonals at most TOL x its mean edge "
                        "length apart (default 1e-3), held exactly by the final polish")


def problem_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """:func:`selfsupport.api.solve` keywords from :func:`add_problem_arguments`."""
    from selfsupport.io.loadcases import parse_vertex_value

    def vertex_map(items: Sequence[str], what: str) -> dict[int, float]:
        out: dict[int, float] = {}
        for text in items:
            v, x = parse_vertex_value(text, what)
            out[v] = out.get(v, 0.0) + x
        return out

    from formulations import Planar

    constraints: list[Any] = [name for name, on in (("hull", args.hull), ("fixed_top_view", args.fixed_top_view)) if on]
    planar = getattr(args, "planar", None)
    if planar is not None:  # (its range is checked by its argparse type)
        constraints.append(Planar(tol=planar))
    return {"objective": list(args.objective) or None, "point_loads": vertex_map(args.point_load, "--point-load"),
            "extra_mass": vertex_map(args.extra_mass, "--extra-mass"), "load_cases": args.load_cases,
            "constraints": constraints}


def _run_solve(args: argparse.Namespace) -> int:
    started = time.perf_counter()  # --time-limit counts from here: reading the input is part of the run
    from selfsupport import api
    from selfsupport.core.progress import ProgressDisplay
    from selfsupport.io.safety import check_output_dir, check_outputs, interrupted_path
    from selfsupport.methods.memory import check_scene_spec
    from selfsupport.methods.staggered import parse_option

    out = Path(args.out)
    inputs = scene_inputs(args) + [("--load-cases file", args.load_cases), ("--bounds file", args.bounds)]
    check_network_out(out, args.format, inputs)
    if args.report:
        check_output_dir(args.report, what="--report", files=report_files(), inputs=inputs + [("--out", args.out)])
    options = dict(parse_option(o) for o in args.option)
    method = args.method  # ("auto": a subdivided design large enough goes up its own levels)
    check_scene_spec(args.scene, method, args.max_memory)  # a built-in shape: before it is built
    scene = load_scene(args.scene, supports=args.supports, up=args.up)
    if args.subdivide:  # (of the design a network file stores, not of its network)
        from dataclasses import replace

        from selfsupport.core.subdivision import subdivide_scene, subdivided_vertex_count
        from selfsupport.methods.memory import check_memory

        design = api.design_of(scene)[0]
        # (the refined mesh's size, refused before it is built: each step quadruples it)
        check_memory(subdivided_vertex_count(design.mesh, args.subdivide), method, args.max_memory)
        scene = subdivide_scene(design, args.subdivide)
        if "design" in scene.meta:  # (a network file: its stored network cannot start this mesh)
            info = {**scene.meta["design"], "start": f"the stored reference subdivided {args.subdivide}x"}
            scene = replace(scene, meta={**scene.meta, "design": info})
    if args.triangulate:  # (after --subdivide, whose steps make quads again)
        scene = api.triangulated_design(scene)
    from formulations.problem import MPA

    progress = ProgressDisplay(enabled=False if args.quiet else None)
    kw = dict(method=method, backend=args.backend, density=args.density, thickness=args.thickness, w_max=args.wmax,
              eps=args.eps, bounds=args.bounds, max_stress=None if args.max_stress is None else args.max_stress * MPA,
              tol=args.tol, max_iter=args.max_iter, progress=progress, options=options, max_memory=args.max_memory,
              **problem_kwargs(args))
    result = api.solve(scene, time_limit=args.time_limit, started=started, **kw)
    # a network file is solved for its stored reference (api.design_of): distances, the hull
    # warning and the summary's scale refer to that design, not to the stored network
    scene, _ = api.design_of(scene)
    note = scene.meta.get("design", {}).get("note")
    if note:
        _err(f"warning: {note}")
    print_warnings(result, scene)
    fmt = args.format
    if result.status == "interrupted" and not args.keep_partial:
        out, fmt = interrupted_path(out), None  # an interrupted run never replaces --out (see --keep-partial)
        check_outputs([("--out", out)], inputs)
    write_network_out(out, result, fmt, scene=_scene_info(scene, args))
    rows = summary_rows(result, scene)
    if result.parameters.get("planar_finish") is not None:
        from selfsupport.remesh.planar import finish_summary

        rows.append(("planar finish", finish_summary(result)))
    print_table(f"selfsupport solve -> {out}", rows)
    if args.report:
        _write_figures(result, Path(args.report), scene.name)
    if not result.converged:
        where = f"; the network so far is in {out}" if result.status == "interrupted" else ""
        _err(_not_converged_line(result) + where)
    return STATUS_EXIT.get(result.status, EXIT_CODES["not_converged"])


def _scene_info(scene, args: argparse.Namespace) -> dict[str, Any]:
    info: dict[str, Any] = {"name": scene.name, "input": args.scene}
    if getattr(args, "supports", None) is not None:
        info["supports_from"] = args.supports
    if getattr(args, "up", None) is not None:
        info["up"] = args.up
    return info


# ----------------------------------------------------------------------------- check
def _check_args(p: argparse.ArgumentParser) -> None:
    add_scene_arguments(p, metavar="MESH_OR_NET")
    add_load_arguments(p, default=False)
    p.add_argument("--tol", type=tolerance, default=DEFAULT_CHECK_TOL,
                   help=f"max relative error that counts as self-supporting, in (0, 1] (default {DEFAULT_CHECK_TOL:g})")
    p.add_argument("--wmax", type=positive_float, default=None, metavar="W", help="upper weight bound [N/m]")
    add_network_out_arguments(p, required=False, what="also write the network with the fitted weights, its status "
                              "self_supporting or not_self_supporting")


def _run_check(args: argparse.Namespace) -> int:
    from selfsupport import api

    if args.out is not None:
        check_network_out(args.out, args.format, scene_inputs(args))
    elif args.format is not None:
        raise InputError("--format names the format of --out; give --out too")
    spec = args.scene
    if spec.startswith("shape:"):
        target: Any = load_scene(spec, supports=args.supports, up=args.up)
        supports, up = None, None
    else:
        if not Path(spec).exists():
            raise InputError(f"{spec}: no such file; give a mesh, scene or network file")
        target, supports, up = spec, args.supports, args.up
    rep = api.check(target, supports=supports, up=up, density=args.density, thickness=args.thickness,
                    tol=args.tol, w_max=args.wmax)
    if args.out is not None:
        write_network_out(args.out, rep.network, args.format, scene=_scene_info(rep, args), **rep.file_fields())
    print_table(f"selfsupport check {spec}" + (f" -> {args.out}" if args.out else ""), rep.rows())
    # (a line of its own: as a table row its length would wrap the table's long labels)
    from selfsupport.core import evidence

    print(f"support reactions of the fitted weights: {evidence.reaction_line(rep.network.reaction_summary())}")
    print(check_verdict(rep))
    ok = rep.self_supporting and rep.stored_self_supporting is not False
    return EXIT_CODES["ok"] if ok else EXIT_CODES["not_self_supporting"]


def check_verdict(rep) -> str:
    """The one-line verdict of ``check``: which weights were judged (fitted, and the stored ones
    of a network file) and what they say. Exit 0 needs every judged set to say yes."""
    fitted = (f"compressive weights fitted to this surface (min {rep.min_weight:.3g} N/m) balance the self-weight "
              f"to a max relative error of {rep.max_relative_error:.2e} <= {rep.tol:g}")
    if rep.stored_self_supporting is None:
        if rep.self_supporting:
            return f"self-supporting: {fitted}."
        return (f"NOT self-supporting: the best compressive weights fitted to this surface leave a max relative "
                f"error of {rep.max_relative_error:.2e} > {rep.tol:g}, so it cannot stand as it is; 'selfsupport "
                "solve' finds a nearby surface that can.")
    stored = (f"the stored weights (min {rep.stored_min_weight:.3g} N/m, max relative error "
              f"{rep.stored_max_relative_error:.2e} with the stored loads)")
    if rep.stored_self_supporting and rep.self_supporting:
        return f"self-supporting: {stored} are compressive and in equilibrium, and {fitted}."
    why = ("include tension (negative weights)" if rep.stored_min_weight < 0
           else f"are not in equilibrium (> {rep.tol:g})") if not rep.stored_self_supporting else "are compressive and in equilibrium"
    if rep.self_supporting:
        return (f"NOT self-supporting as stored: {stored} {why}; {fitted}, so re-solving or refitting this "
                "file gives a valid network.")
    return (f"NOT self-supporting: {stored} {why}, and the best compressive weights fitted to this surface leave a "
            f"max relative error of {rep.max_relative_error:.2e} > {rep.tol:g}; 'selfsupport solve' finds a "
            "nearby surface that can stand.")


# ------------------------------------------------------------------------------ demo
#: The demo's default reference: a vault on four pillars, which has to move to stand.
DEMO_SHAPE = "pillar_vault"
DEMO_VERTICES = 676


def _demo_args(p: argparse.ArgumentParser) -> None:
    from selfsupport.core.shapes import SHAPES

    p.add_argument("--out", "-o", default="demo-out", metavar="DIR",
                   help="output directory (default ./demo-out): network.json, report.md, figures and view.html")
    p.add_argument("--shape", choices=sorted(SHAPES), default=DEMO_SHAPE, help=f"built-in shape (default {DEMO_SHAPE})")
    p.add_argument("--vertices", type=positive_int, default=DEMO_VERTICES, metavar="N",
                   help=f"about this many vertices (default {DEMO_VERTICES})")
    add_load_arguments(p)
    p.add_argument("--quiet", "-q", action="store_true", help="no progress display")


def _run_demo(args: argparse.Namespace) -> int:
    from selfsupport import api
    from selfsupport.core.progress import ProgressDisplay
    from selfsupport.core.shapes import make_shape
    from selfsupport.io import read_network, write_network
    from selfsupport.io.atomic import atomic_write_text
    from selfsupport.io.safety import check_output_dir

    out = Path(args.out)
    check_output_dir(out, files=["network.json", "report.md", *report_files()])
    scene = make_shape(args.shape, n_vertices=args.vertices)
    progress = ProgressDisplay(enabled=False if args.quiet else None)
    result = api.solve(scene, density=args.density, thickness=args.thickness, progress=progress)
    print_warnings(result, scene)
    net_path, report_path = out / "network.json", out / "report.md"
    write_network(net_path, result, scene={"name": scene.name, "input": f"shape:{args.shape}:{args.vertices}"})
    reread = read_network(net_path).max_relative_error()
    rows = summary_rows(result, scene)
    figures = _write_figures(result, out, scene.name)
    atomic_write_text(report_path, demo_report(result, rows, args, reread) + "\n" + figures.markdown() + "\n")
    print_table(f"selfsupport demo -> {net_path}, {report_path}", rows)
    if not result.converged:
        _err(_not_converged_line(result))
    return STATUS_EXIT.get(result.status, EXIT_CODES["not_converged"])


def _write_figures(result, directory: Path, name: str):
    """Figures and the HTML view next to a network (``solve --report``, the demo)."""
    from selfsupport.figures.report import write_report

    files = write_report(result, directory, name=name)
    print(f"figures -> {directory}/ ({files.markdown().count('.png')} PNG, view.html)")
    return files


def _fmt(x: Any) -> str:
    if isinstance(x, bool) or x is None:
        return "" if x is None else ("yes" if x else "no")
    if isinstance(x, float):
        return f"{x:.3e}"
    return str(x)


#: History columns of the demo report: (header, record key).
REPORT_COLUMNS: tuple[tuple[str, str], ...] = (
    ("iteration", "iteration"), ("max rel. error", "max_rel_error"), ("E", "E"), ("alpha", "alpha"),
    ("beta", "beta"), ("accepted", "accepted"), ("weights at eps", "n_at_lower"),
    ("fit [s]", "t_weights"), ("positions [s]", "t_positions"))


def demo_report(result, rows: Sequence[tuple[str, str]], args: argparse.Namespace, reread: float) -> str:
    """The demo's Markdown report: summary, per-iteration history, how to reproduce."""
    lines = [f"# selfsupport demo: {rows[0][1]}", "",
             f"Reference: built-in `{args.shape}` (~{args.vertices} vertices), self-weight "
             f"{args.density:g} kg/m³ × {args.thickness:g} m, supports as built in; method "
             f"`{result.method}` / `{result.backend}`.", "",
             "## Summary", "", "| quantity | value |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in rows]
    lines += ["", f"Max relative error recomputed from `network.json` as written: {reread:.3e}.", ""]
    if result.message:
        lines += [f"Solver message: {result.message}", ""]
    lines += ["## Iterations", "", "| " + " | ".join(h for h, _ in REPORT_COLUMNS) + " |",
              "|" + "---|" * len(REPORT_COLUMNS)]
    for rec in result.history:
        lines.append("| " + " | ".join(_fmt(rec.get(k)) for _, k in REPORT_COLUMNS) + " |")
    lines += ["", "The `polish` row freezes the weights and solves the positions exactly, with loads "
              "re-estimated from the geometry until consistent.", "",
              "Reproduce: `selfsupport demo --shape {} --vertices {} --out {}`".format(args.shape, args.vertices, args.out),
              ""]
    return "\n".join(lines)


# --------------------------------------------------------------------------- parser
COMMANDS: dict[str, Command] = {
    "solve": Command("find the thrust network nearest to a reference surface and write it as JSON",
                     _solve_args, _run_solve),
    "check": Command("is a mesh (or a network file) self-supporting as it is? (exit 0 yes, 1 no)",
                     _check_args, _run_check),
    "demo": Command("solve a built-in reference and write network.json and report.md", _demo_args, _run_demo),
}

#: The modules of :mod:`selfsupport.cli` that hold no commands of their own.
NOT_COMMAND_MODULES = frozenset({"common", "__main__"})


@dataclass(frozen=True)
class CommandEntry:
    """A command as the top-level parser lists it, before its module is imported: the module whose
    ``COMMANDS`` defines it and its one-line help."""

    module: str
    help: str


#: The start of a module's ``COMMANDS`` declaration (``COMMANDS = {`` or ``COMMANDS: dict[...] = {``).
_DECLARATION = re.compile(r"^COMMANDS\b[^=\n]*=", re.MULTILINE)


def declared_commands(source: str, module: str) -> dict[str, str]:
    """Name -> one-line help of the ``COMMANDS`` a module's source declares, read without running it.

    The declaration is the module-level statement ``COMMANDS ... = {...}``: a dict literal whose
    keys are strings and whose values are ``Command("help", ...)`` calls with the help a string
    literal (positional or ``help=``). Only that statement is parsed: it ends at the first line that
    starts in the first column with anything but a closing bracket or a comment.

    >>> declared_commands('COMMANDS = {\\n    "hi": Command("say hi", add, run),\\n}\\n\\n\\ndef f():\\n    pass\\n', "m")
    {'hi': 'say hi'}
    """
    bad = TypeError(f"{module} must declare COMMANDS as a dict literal of \"name\": Command(\"one-line help\", "
                    "add_arguments, run) entries, the help a string literal (--help lists it without importing "
                    "the module)")
    found = _DECLARATION.search(source)
    if found is None:
        raise bad
    lines = source[found.start():].splitlines()
    end = next((k for k in range(1, len(lines)) if lines[k][:1] not in ("", " ", "\t", "}", ")", "]", "#")),
               len(lines))
    try:
        value = ast.parse("\n".join(lines[:end])).body[0].value  # type: ignore[attr-defined]
    except (SyntaxError, IndexError, AttributeError):
        raise bad from None
    if not isinstance(value, ast.Dict):
        raise bad
    out: dict[str, str] = {}
    for key, call in zip(value.keys, value.values):
        helps = ([call.args[0]] if call.args else [k.value for k in call.keywords if k.arg == "help"]) \
            if isinstance(call, ast.Call) else []
        if not (isinstance(key, ast.Constant) and isinstance(key.value, str) and helps
                and isinstance(helps[0], ast.Constant) and isinstance(helps[0].value, str)):
            raise bad
        out[key.value] = helps[0].value
    return out


def command_index() -> dict[str, CommandEntry]:
    """Every command, name -> :class:`CommandEntry`, in the order ``selfsupport --help`` lists them:
    the built-ins of :data:`COMMANDS`, then the ``COMMANDS`` of every other module of
    :mod:`selfsupport.cli` (by module name), read from its source (:func:`declared_commands`) without
    importing it. A name declared twice is refused."""
    import selfsupport.cli as package

    index = {name: CommandEntry(__name__, cmd.help) for name, cmd in COMMANDS.items()}
    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda i: i.name):
        if info.name in NOT_COMMAND_MODULES:
            continue
        module = f"{package.__name__}.{info.name}"
        spec = info.module_finder.find_spec(module, None)  # type: ignore[call-arg]
        source = spec.loader.get_source(module) if spec is not None and spec.loader is not None else None
        if source is None:  # (no source to read: a compiled module is imported instead)
            declared = {name: cmd.help for name, cmd in _module_commands(module).items()}
        else:
            declared = declared_commands(source, module)
        clash = sorted(set(declared) & set(index))
        if clash:
            raise TypeError(f"{module} redefines command(s) {clash}")
        index.update({name: CommandEntry(module, text) for name, text in declared.items()})
    return index


def _module_commands(module: str) -> dict[str, Command]:
    commands = getattr(importlib.import_module(module), "COMMANDS", None)
    if not isinstance(commands, dict) or not all(isinstance(c, Command) for c in commands.values()):
        raise TypeError(f"{module} must define COMMANDS: dict[str, Command]")
    return commands


def load_command(name: str, index: dict[str, CommandEntry] | None = None) -> Command:
    """The :class:`Command` ``name`` of :func:`command_index` (``index``, if given): its module is
    imported now."""
    entry = (command_index() if index is None else index)[name]
    commands = COMMANDS if entry.module == __name__ else _module_commands(entry.module)
    if name not in commands:
        raise TypeError(f"{entry.module}: its COMMANDS declares {name!r} but does not define it")
    return commands[name]


def discover_commands() -> dict[str, Command]:
    """Every command of :func:`command_index`, each module imported."""
    index = command_index()
    return {name: load_command(name, index) for name in index}


def build_parser(commands: dict[str, Command] | None = None, *,
                 load: Collection[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser with one subparser per command.

    Parameters
    ----------
    commands
        The commands; default every command of :func:`command_index`.
    load
        Import and add the arguments of these commands alone (the one the command line names, or
        none for the top-level help): the others are listed with their help but take no
        arguments. Default: every command's.
    """
    index = command_index() if commands is None else None
    helps = {n: c.help for n, c in (commands if index is None else index).items()}  # type: ignore[union-attr]
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                        help="show the full traceback on errors")
    parser = _Parser(prog=PROG, parents=[common],
                     description="Design of self-supporting surfaces (Vouga et al., SIGGRAPH 2012): "
                                 "thrust networks in equilibrium near a reference mesh.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name, text in helps.items():
        sp = sub.add_parser(name, help=text, description=text, parents=[common])
        if load is None or name in load:
            cmd = load_command(name, index) if commands is None else commands[name]
            cmd.add_arguments(sp)
            sp.set_defaults(_run=cmd.run)
    return parser


def command_named(argv: Sequence[str]) -> str | None:
    """The command an argument list names: its first word that is not an option (the top-level
    options ``--debug``, ``--version``, ``--help`` take no value), or ``None``.

    >>> command_named(["--debug", "solve", "m.obj", "--out", "n.json"])
    'solve'
    """
    return next((a for a in argv if not a.startswith("-")), None)


def _axis_values_joined(argv: list[str]) -> list[str]:
    """``--up -y`` as ``--up=-y`` and ``--load -1e3`` as ``--load=-1e3``: argparse takes a value that
    starts with "-" for an option unless it is a plain negative number like ``-5`` (and the help and
    the errors name ``-y`` and ``-z`` as axes).

    >>> _axis_values_joined(["solve", "m.obj", "--up", "-y", "--out", "n.json"])
    ['solve', 'm.obj', '--up=-y', '--out', 'n.json']
    >>> _axis_values_joined(["construct", "--load", "-1e3", "--alpha", "-.5"])
    ['construct', '--load=-1e3', '--alpha=-.5']
    """
    out: list[str] = []
    for tok in argv:
        prev = out[-1] if out else ""
        if prev == "--up" and tok in ("-x", "-y", "-z"):
            out[-1] = f"--up={tok}"
        elif prev.startswith("--") and "=" not in prev and _is_number(tok) and tok.startswith("-"):
            out[-1] = f"{prev}={tok}"
        else:
            out.append(tok)
    return out


@contextlib.contextmanager
def sigterm_interrupts() -> Iterator[None]:
    """While inside, SIGTERM raises :class:`KeyboardInterrupt`, as Ctrl-C does.

    SIGTERM's default action ends the process at once, so no ``finally`` runs and an atomic
    write in progress leaves its temporary file behind; raised as an interrupt, the write's
    cleanup runs and a solve stops with its best network, as on Ctrl-C. The previous handler is
    restored on exit. Outside the main thread (where no handler can be set) nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt(f"signal {signum}")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextlib.contextmanager
def _collector_around_command() -> Iterator[Callable[[], None]]:
    """The cyclic garbage collector around a command: off while its modules are imported; once
    the function this yields is called (they are), the objects alive then (numpy's, scipy's and
    the project's modules: ~50,000) frozen out of its sight (:func:`gc.freeze`) and the collector
    back on for the run; on exit, as it was.

    Imports leave next to no cyclic garbage, yet the collector walked their objects again and
    again as they came (~0.015 CPU s of a solve's start), and a full collection inside a solve
    of structural's 527 vertices took 0.017 CPU s, a tenth of the solve, to find nothing among
    them. Nothing changes when objects were frozen already or the collector was off (a caller's
    own settings)."""
    if gc.get_freeze_count() or not gc.isenabled():
        yield lambda: None
        return

    def imported() -> None:
        gc.freeze()
        gc.enable()

    gc.disable()
    try:
        yield imported
    finally:
        gc.enable()
        gc.unfreeze()


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (:func:`console_main` ends the process with it)."""
    with sigterm_interrupts():
        return _main(argv)


def console_main() -> NoReturn:
    """The console script and ``python -m selfsupport``: :func:`main`, then the process ends with
    its exit code once stdout and stderr are flushed and the exit handlers (:mod:`atexit`) have
    run, without the interpreter's teardown: freeing the ~600 modules' objects one by one and
    stopping the BLAS libraries' thread pools took ~0.09 CPU s of a 0.6 s solve of a 527-vertex
    mesh, for nothing a finished command needs. Where another Python thread still runs, or a
    stream cannot be flushed (a closed pipe), it exits as Python does."""
    code = main()
    if threading.active_count() == 1:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        except (OSError, ValueError):
            sys.exit(code)
        atexit._run_exitfuncs()  # (what the teardown would have run first)
        os._exit(code)
    sys.exit(code)


def _main(argv: Sequence[str] | None) -> int:
    argv = _axis_values_joined(list(sys.argv[1:] if argv is None else argv))
    debug = "--debug" in argv
    try:
        name = command_named(argv)
        with _collector_around_command() as imported:
            args = build_parser(load=() if name is None else (name,)).parse_args(argv)
            imported()
            return int(args._run(args))
    except _UsageError as e:
        if debug:
            raise
        _err(f"error: {e}")
        return EXIT_CODES["input"]
    except KeyboardInterrupt:
        if debug:
            raise
        _err("interrupted; nothing was written")
        return EXIT_CODES["interrupted"]
    except SelfSupportError as e:
        if debug:
            raise
        _err(f"error: {_one_line(e)}")
        return int(e.exit_code)
    except OSError as e:
        if debug:
            raise
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        _err(f"error: {where}{e.strerror or e}")
        return EXIT_CODES["input"]
    except (ValueError, json.JSONDecodeError, UnicodeDecodeError) as e:
        if debug:
            raise
        _err(f"error: {_one_line(e)}")
        return EXIT_CODES["input"]
    except Exception as e:  # noqa: BLE001 - the last line of defence: one line, not a traceback
        if debug:
            raise
        _err(f"internal error: {type(e).__name__}: {_one_line(e)} (rerun with --debug for the traceback "
             "and report it)")
        return EXIT_CODES["internal"]


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


if __name__ == "__main__":  # pragma: no cover
    console_main()
