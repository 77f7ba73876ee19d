"""Progress display for long solves: one line per outer iteration on stderr.

:class:`ProgressDisplay` is a ``progress`` callback for any method: it receives the method's
history records (dicts) and prints the fields it knows — iteration (or IPOPT load round),
max relative error, fit energy E, the penalties α and β, the time since the start — with
rich. It prints nothing when disabled (``--quiet``) or when its stream is not a terminal
(logs and pipes get only the final summary the CLI prints); then rich is not imported at all
(~0.03 CPU s of a command's start).

>>> import io
>>> from rich.console import Console
>>> out = io.StringIO()
>>> p = ProgressDisplay(console=Console(file=out, force_terminal=True, no_color=True, width=100))
>>> p({"iteration": 1, "max_rel_error": 0.5, "E": 2.0, "alpha": 1.0, "beta": 0.1})
>>> "5.00e-01" in out.getvalue()
True
"""
from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable

if TYPE_CHECKING:
    from rich.console import Console

__all__ = ["Column", "COLUMNS", "ProgressDisplay", "may_be_terminal"]


def may_be_terminal(stream: Any) -> bool:
    """Whether rich may treat ``stream`` as a terminal (styles, the terminal's width): a TTY, or
    an environment that forces it (``FORCE_COLOR``, ``TTY_COMPATIBLE``). False means rich would
    certainly not, so plain text serves."""
    if "FORCE_COLOR" in os.environ or "TTY_COMPATIBLE" in os.environ:
        return True
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty and isatty())
    except ValueError:  # (a closed stream)
        return False


@dataclass(frozen=True)
class Column:
    """One column: its header, the record keys it reads (first present wins), its format."""

    header: str
    keys: tuple[str, ...]
    fmt: Callable[[Any], str]
    width: int = 10


def _sci(x: Any) -> str:
    return f"{x:.2e}" if isinstance(x, (int, float)) else str(x)


def _plain(x: Any) -> str:
    return str(x)


#: Columns in display order. Staggered records carry ``iteration``, ``max_rel_error``, ``E``,
#: ``alpha``, ``beta`` (and ``level`` under the multilevel method); IPOPT records ``round``,
#: ``stage``, ``max_relative_error``, ``objective``, ``load_change``. A column is shown when the
#: first record has one of its keys.
COLUMNS: tuple[Column, ...] = (
    Column("level", ("level",), _plain, 5),
    Column("iter", ("iteration", "round"), _plain, 9),
    Column("stage", ("stage",), _plain, 7),
    Column("max rel err", ("max_rel_error", "max_relative_error"), _sci, 11),
    Column("E", ("E",), _sci),
    Column("objective", ("objective",), _sci),
    Column("alpha", ("alpha",), _sci, 9),
    Column("beta", ("beta",), _sci, 9),
    Column("load chg", ("load_change",), _sci, 9),
    Column("accepted", ("accepted",), lambda a: "yes" if a else "no", 8),
)


class ProgressDisplay:
    """A ``progress`` callback printing one aligned line per history record.

    Parameters
    ----------
    console
        Where to print (default: a rich console on stderr; none when nothing would be printed).
    enabled
        ``False`` silences it; ``None`` (default) means "only if the console is a terminal".
    """

    def __init__(self, console: Console | None = None, enabled: bool | None = None) -> None:
        if console is None and (enabled is False or (enabled is None and not may_be_terminal(sys.stderr))):
            console, enabled = None, False  # (nothing to print: no console, no rich)
        elif console is None:
            from rich.console import Console

            console = Console(stderr=True, highlight=False)
        self.console = console
        self.enabled = console.is_terminal if enabled is None else bool(enabled)
        self.columns: tuple[Column, ...] | None = None
        self.t0 = time.perf_counter()
        self.records = 0

    def _line(self, cells: list[str]) -> str:
        cols = self.columns or ()
        return "  ".join(c.rjust(col.width) for c, col in zip(cells, cols)) + "  " + cells[-1].rjust(8)

    def __call__(self, record: dict[str, Any]) -> None:
        self.records += 1
        if not self.enabled:
            return
        if self.columns is None:
            self.columns = tuple(c for c in COLUMNS if any(k in record for k in c.keys))
            self.console.print(self._line([c.header for c in self.columns] + ["time"]), style="bold")
        cells = []
        for col in self.columns:
            key = next((k for k in col.keys if k in record), None)
            cells.append("" if key is None else col.fmt(record[key]))
        cells.append(f"{time.perf_counter() - self.t0:.1f} s")
        self.console.print(self._line(cells))
