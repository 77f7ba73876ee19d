"""Where a command may write: one place for every rule that keeps a user's files safe.

Every file the project writes goes through :func:`selfsupport.io.atomic.atomic_write_text` /
``atomic_write_bytes``, which call :func:`write_target`; every command checks its outputs up
front, before any long computation, with :func:`check_outputs`. The rules:

* **Regular files or new paths only.** A directory, a FIFO, a character or block device or a
  socket is refused with one line (an atomic write would otherwise *replace* ``/dev/null`` by a
  regular file, or block on a FIFO).
* **Symlinks are written through.** The write goes to the link's final target (created if the
  link dangles); the link itself stays a link.
* **Never an input.** An output that resolves to one of the command's input files (same
  device and inode: another spelling of the path, a symlink or a hard link) is refused.
* **Output folders** (``--report DIR``, ``demo --out DIR``) must be folders or new paths.
"""
from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Iterable

from ..errors import InputError

__all__ = ["write_target", "check_output_file", "check_output_dir", "check_outputs", "same_file",
           "interrupted_path"]

_KINDS = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a directory"))


def _kind(mode: int) -> str | None:
    """What a non-regular file is, or ``None`` for a regular file."""
    for test, name in _KINDS:
        if test(mode):
            return name
    return None if stat.S_ISREG(mode) else "not a regular file"


def write_target(path: str | os.PathLike, *, what: str = "") -> Path:
    """The file a write of ``path`` must replace: ``path`` itself, or the final target of a
    symlink (relative links resolved from the link's folder; a dangling link's target is
    created). Raises :class:`InputError` when that target exists and is not a regular file."""
    p = Path(path)
    target = Path(os.path.realpath(p)) if p.is_symlink() else p
    try:
        st = os.stat(target)
    except FileNotFoundError:
        return target
    except OSError as e:
        raise InputError(f"cannot write {_label(what, p)}: {e.strerror or e}; check the path and permissions") from None
    kind = _kind(st.st_mode)
    if kind is not None:
        via = f" (the symlink points to {target})" if target != p else ""
        fix = f"give a file name such as {p / 'out.json'}" if kind == "a directory" else "give a regular file or a new path"
        raise InputError(f"refusing to write {_label(what, p)}: it is {kind}{via}; {fix}")
    return target


def _label(what: str, p: Path) -> str:
    return f"{what} {p}" if what else str(p)


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether two paths name the same existing file (device and inode, symlinks followed)."""
    try:
        sa, sb = os.stat(a), os.stat(b)
    except OSError:
        return False
    return (sa.st_dev, sa.st_ino) == (sb.st_dev, sb.st_ino)


def _writable_parent(p: Path, what: str, *, folder: bool = False) -> None:
    """The nearest existing folder above ``p`` (``folder``: from ``p`` itself on, which is to be a
    folder) must be a writable folder."""
    parent = p if folder else p.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if parent.exists() and not parent.is_dir():
        raise InputError(f"cannot write {_label(what, p)}: {parent} is a file, not a folder; give another path")
    if not os.access(parent, os.W_OK):
        raise InputError(f"cannot write {_label(what, p)}: {parent} is not writable; give another path")


def check_output_file(path: str | os.PathLike, *, what: str = "--out",
                      inputs: Iterable[tuple[str, str | os.PathLike]] = ()) -> Path:
    """Check an output file before the work starts (see the module docstring); returns the path
    the write will replace."""
    p = Path(path)
    target = write_target(p, what=what)
    _refuse_inputs(p, what, inputs)
    _writable_parent(target, what)
    return target


def check_output_dir(path: str | os.PathLike, *, what: str = "--out", files: Iterable[str] = (),
                     inputs: Iterable[tuple[str, str | os.PathLike]] = ()) -> Path:
    """Check an output folder (existing folder or new path) and the ``files`` to be written in it."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(f"{what} {p} is a file, not a folder; give a folder (it is created if missing)")
    inputs = list(inputs)
    _refuse_inputs(p, what, inputs)
    for name in files:
        f = p / name
        if f.exists() or f.is_symlink():
            write_target(f, what=f"{what} file")
            _refuse_inputs(f, f"{what} file", inputs)
    _writable_parent(p, what, folder=True)
    return p


def check_outputs(files: Iterable[tuple[str, str | os.PathLike | None]] = (),
                  inputs: Iterable[tuple[str, str | os.PathLike | None]] = ()) -> None:
    """:func:`check_output_file` for every ``(option, path)`` in ``files`` (``None`` paths are
    skipped), against every ``(name, path)`` in ``inputs``."""
    ins = [(n, q) for n, q in inputs if q is not None]
    for what, path in files:
        if path is not None:
            check_output_file(path, what=what, inputs=ins)


def _refuse_inputs(p: Path, what: str, inputs: Iterable[tuple[str, str | os.PathLike]]) -> None:
    for name, q in inputs:
        if q is not None and same_file(p, q):
            raise InputError(f"refusing to write {what} {p}: it is the input {name} {q}; "
                             "give another output path")


def interrupted_path(out: str | os.PathLike) -> Path:
    """Where ``solve`` writes an interrupted result instead of ``out``: ``NAME.interrupted.json``."""
    p = Path(out)
    stem = p.name[:-5] if p.name.lower().endswith(".json") else p.name
    return p.with_name(f"{stem}.interrupted.json")
