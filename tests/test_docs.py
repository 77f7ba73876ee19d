"""The documentation's examples, run as tests.

* Every fenced ``console`` block preceded by ``<!-- run -->`` in README.md or docs/**/*.md is
  run: its ``$ `` lines are commands (run by bash in one temporary folder per page, in page
  order, with the virtual environment's ``selfsupport`` first on the PATH), the lines after a
  command are its expected stdout followed by its stderr, compared with doctest's checker
  (``...`` matches anything, whitespace is normalised). Every command must exit 0, except that
  ``$ echo $?`` prints the previous command's exit code, which is then compared like output.
* ``<!-- run: slow -->`` marks a block that takes long: it runs with the slow tests only.
* ``<!-- run: serve -->`` marks a server: its one command is started, its first line of output
  compared, and the process stopped.
* A fenced block with ``title="NAME"`` (a file the page shows) is written to NAME in the page's
  folder before the commands after it run.
* ``>>>`` examples in the pages run as doctests, in a temporary folder.
"""
from __future__ import annotations

import doctest
import os
import re
import selectors
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])
BIN = Path(sys.executable).parent
#: rich wraps its tables to the terminal width: wide enough that no row wraps
ENV = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}", "COLUMNS": "200",
       "NO_COLOR": "1"}
OPTIONS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
FENCE = re.compile(r"^(?P<indent>[ \t]*)(?P<fence>```+)(?P<info>[^\n]*)$")
MARK = re.compile(r"<!--\s*run(?::\s*(?P<kind>\w+))?\s*-->")


@dataclass
class Block:
    """A fenced block of a page: a file to write, or commands to run (with expected output)."""

    line: int
    kind: str                       # "file", "run", "slow" or "serve"
    text: str
    name: str = ""                  # the file's name for kind "file"
    commands: list[tuple[str, str]] = field(default_factory=list)


def blocks(page: Path) -> list[Block]:
    """The page's files and runnable blocks, in order."""
    lines = page.read_text(encoding="utf-8").splitlines()
    out: list[Block] = []
    pending: str | None = None
    i = 0
    while i < len(lines):
        m = MARK.search(lines[i])
        if m:
            pending = m.group("kind") or "run"
            i += 1
            continue
        f = FENCE.match(lines[i])
        if not f:
            if lines[i].strip():
                pending = None
            i += 1
            continue
        indent, fence, info = f.group("indent"), f.group("fence"), f.group("info")
        start, body = i + 1, []
        i += 1
        while i < len(lines) and not lines[i].strip().startswith(fence):
            body.append(lines[i][len(indent):] if lines[i].startswith(indent) else lines[i].lstrip())
            i += 1
        i += 1
        title = re.search(r'title="([^"]+)"', info)
        if title:
            out.append(Block(start, "file", "\n".join(body) + "\n", name=title.group(1)))
        elif pending is not None:
            if not info.strip().startswith("console"):
                raise AssertionError(f"{page}:{start}: a run marker must precede a ```console block")
            out.append(Block(start, pending, "\n".join(body), commands=session(body)))
        pending = None
    return out


def session(body: list[str]) -> list[tuple[str, str]]:
    """``[(command, expected output)]`` of a console block."""
    cmds: list[tuple[str, list[str]]] = []
    for line in body:
        if line.startswith("$ "):
            cmds.append((line[2:], []))
        elif cmds:
            cmds[-1][1].append(line)
        else:
            raise AssertionError(f"console block starts with output, not a '$ ' command: {line!r}")
    return [(c, "\n".join(o)) for c, o in cmds]


def same(expected: str, got: str) -> bool:
    if not expected.strip():
        return True
    return doctest.OutputChecker().check_output(expected.rstrip() + "\n", got.rstrip() + "\n", OPTIONS)


def run_serve(cmd: str, expected: str, cwd: Path, where: str) -> None:
    """Start a server, compare its first line of output, stop it (our own child, by its id)."""
    proc = subprocess.Popen(["bash", "-c", f"exec {cmd}"], cwd=cwd, env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        sel = selectors.DefaultSelector()
        sel.register(proc.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + 120
        first = ""
        while not first and time.monotonic() < deadline and proc.poll() is None:
            if sel.select(timeout=1):
                first = proc.stdout.readline()
        assert same(expected.splitlines()[0], first), f"{where}: {cmd}\nexpected {expected!r}\ngot {first!r}"
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def run_page(page: Path, tmp: Path, *, slow: bool) -> int:
    """Run the page's blocks in ``tmp``; returns how many commands ran."""
    ran = 0
    for b in blocks(page):
        where = f"{page.name}:{b.line}"
        if b.kind == "file":
            (tmp / b.name).write_text(b.text, encoding="utf-8")
            continue
        if b.kind == "slow" and not slow:
            continue
        if b.kind == "serve":
            (cmd, expected), = b.commands
            run_serve(cmd, expected, tmp, where)
            ran += 1
            continue
        rc = 0
        for k, (cmd, expected) in enumerate(b.commands):
            if cmd.strip() == "echo $?":
                got = str(rc)
                rc = 0
            else:
                p = subprocess.run(["bash", "-c", cmd], cwd=tmp, env=ENV, capture_output=True, text=True,
                                   timeout=600)
                got, rc = p.stdout + p.stderr, p.returncode
                checked = k + 1 < len(b.commands) and b.commands[k + 1][0].strip() == "echo $?"
                if rc != 0 and not checked:
                    pytest.fail(f"{where}: `{cmd}` exited {rc}:\n{got}")
            assert same(expected, got), f"{where}: `{cmd}`\n--- expected\n{expected}\n--- got\n{got}"
            ran += 1
    return ran


def runnable(page: Path, kinds: tuple[str, ...]) -> bool:
    return any(b.kind in kinds for b in blocks(page))


FAST = [p for p in PAGES if runnable(p, ("run", "serve"))]
SLOW = [p for p in PAGES if runnable(p, ("slow",))]


def page_id(p: Path) -> str:
    return str(p.relative_to(ROOT))


@pytest.mark.parametrize("page", FAST, ids=page_id)
def test_page_examples_run_as_printed(page, tmp_path):
    assert run_page(page, tmp_path, slow=False) > 0


@pytest.mark.slow
@pytest.mark.parametrize("page", SLOW, ids=page_id)
def test_page_examples_run_as_printed_with_the_slow_ones(page, tmp_path):
    assert run_page(page, tmp_path, slow=True) > 0


@pytest.mark.parametrize("page", [p for p in PAGES if ">>> " in p.read_text(encoding="utf-8")], ids=page_id)
def test_page_python_examples(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = doctest.testfile(str(page), module_relative=False, optionflags=OPTIONS, verbose=False, report=True)
    assert result.attempted > 0 and result.failed == 0, f"{page}: {result.failed} of {result.attempted} examples failed"


def test_every_command_has_a_guide_page_with_an_example_that_runs():
    """One guide page per subcommand of the CLI, each with a block the tests run."""
    from selfsupport.cli import discover_commands

    pages = ROOT / "docs" / "guide" / "commands"
    for name in discover_commands():
        page = pages / f"{name}.md"
        assert page.is_file(), f"no guide page for `selfsupport {name}` ({page})"
        assert any(b.kind in ("run", "serve") and any(c.startswith(f"selfsupport {name}") for c, _ in b.commands)
                   for b in blocks(page)), f"{page} runs no `selfsupport {name}` example"


def test_the_runner_notices_wrong_output_and_a_failing_command(tmp_path):
    """The harness is not vacuous: a wrong expected line and an unexpected exit code fail, and
    ``echo $?`` checks an expected nonzero exit."""
    page = tmp_path / "p.md"
    page.write_text("<!-- run -->\n```console\n$ echo hello\ngoodbye\n```\n", encoding="utf-8")
    with pytest.raises(AssertionError, match="goodbye"):
        run_page(page, tmp_path, slow=False)
    page.write_text("<!-- run -->\n```console\n$ false\n```\n", encoding="utf-8")
    with pytest.raises(pytest.fail.Exception, match="exited 1"):
        run_page(page, tmp_path, slow=False)
    page.write_text("<!-- run -->\n```console\n$ false\n$ echo $?\n1\n```\n", encoding="utf-8")
    assert run_page(page, tmp_path, slow=False) == 2
