"""Where a command may write: one place for every rule that keeps a user's files safe.

Every file the project writes goes through :func:`selfsupport.io.atomic.atomic_write_text` /
``atomic_write_bytes``, which call :func:`write_target`; every command checks its outputs up
front, before any long computation, with :func:`check_outputs`. The rules:

* **Regular files or new paths only.** A directory, a FIFO, a character or block device or a
  socket is refused with one line (an atomic write would otherwise *replace* ``/dev/null`` by a
  regular file, or block on a FIFO).
* **Never a file the user may not write.** The atomic rename needs write permission on the
  folder only, so it would replace a read-only file; like ``cp`` without ``-f``, an existing
  target is refused when the user has no write permission on it, or when its mode has no write
  bit at all (``chmod a-w``: marked read-only; root passes every permission check, so the mode
  is what keeps such a file from root's runs too).
* **Names the file system takes.** Every name on the way (new folders and the file) must fit
  the file system's ``NAME_MAX``; the temporary name of an atomic write and
  :func:`interrupted_path` shorten their stem to fit, so a name that fits is all it takes.
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

from selfsupport.core.errors import InputError

__all__ = ["write_target", "check_output_file", "check_output_dir", "check_outputs", "same_file",
           "interrupted_path", "name_max", "fit_name", "check_name_lengths"]

#: ``NAME_MAX`` where the file system cannot be asked (no ``os.pathconf``): the usual 255 bytes.
DEFAULT_NAME_MAX = 255

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
    via = f" (the symlink points to {target})" if target != p else ""
    if kind is not None:
        fix = f"give a file name such as {p / 'out.json'}" if kind == "a directory" else "give a regular file or a new path"
        raise InputError(f"refusing to write {_label(what, p)}: it is {kind}{via}; {fix}")
    mode = stat.S_IMODE(st.st_mode)
    if not mode & 0o222:
        raise InputError(f"refusing to write {_label(what, p)}: it is read-only (mode {mode:04o}){via}; "
                         f"make it writable (chmod u+w {target}) or choose another name")
    if not os.access(target, os.W_OK, effective_ids=os.access in os.supports_effective_ids):
        raise InputError(f"refusing to write {_label(what, p)}: it is not writable by this user (mode {mode:04o}, "
                         f"owner uid {st.st_uid}){via}; change its mode or owner (chmod, chown) or choose another name")
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


def name_max(directory: str | os.PathLike) -> int:
    """The longest file name (in bytes) the file system of ``directory`` (or of its nearest
    existing ancestor) takes; :data:`DEFAULT_NAME_MAX` where it cannot be asked."""
    d = Path(os.path.abspath(directory))
    while not os.path.lexists(d) and d != d.parent:
        d = d.parent
    try:
        return int(os.pathconf(d, "PC_NAME_MAX"))
    except (AttributeError, OSError, ValueError):
        return DEFAULT_NAME_MAX


def fit_name(stem: str, suffix: str, limit: int) -> str:
    """``stem + suffix`` with the stem shortened (at a character boundary) until the name's
    file-system encoding is at most ``limit`` bytes.

    >>> fit_name("abcdef", ".tmp", 8)
    'abcd.tmp'
    >>> fit_name("\u00e9\u00e9\u00e9", ".x", 6)
    '\u00e9\u00e9.x'
    """
    room = limit - len(os.fsencode(suffix))
    while stem and len(os.fsencode(stem)) > room:
        stem = stem[:-1]
    return stem + suffix


def check_name_lengths(path: str | os.PathLike, *, what: str = "--out") -> None:
    """Refuse ``path`` when one of its names not yet on disk (folders to be created, the file)
    is longer than the file system takes; an existing name evidently fits."""
    p = Path(os.path.abspath(path))
    parts: list[str] = []
    while not os.path.lexists(p) and p != p.parent:
        parts.append(p.name)
        p = p.parent
    limit = name_max(p)
    for name in reversed(parts):
        n = len(os.fsencode(name))
        if n > limit:
            short = name if len(name) <= 40 else f"{name[:20]}...{name[-12:]}"
            raise InputError(f"cannot write {what}: the name {short!r} in it is too long ({n} bytes; the file "
                             f"system takes at most {limit}); choose a shorter name")


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
    check_name_lengths(p, what=what)
    target = write_target(p, what=what)
    _refuse_inputs(p, what, inputs)
    if target != p:  # (a dangling symlink: its target is created)
        check_name_lengths(target, what=what)
    _writable_parent(target, what)
    return target


def check_output_dir(path: str | os.PathLike, *, what: str = "--out", files: Iterable[str] = (),
                     inputs: Iterable[tuple[str, str | os.PathLike]] = ()) -> Path:
    """Check an output folder (existing folder or new path) and the ``files`` to be written in it."""
    p = Path(path)
    check_name_lengths(p, what=what)
    if p.exists() and not p.is_dir():
        raise InputError(f"{what} {p} is a file, not a folder; give a folder (it is created if missing)")
    inputs = list(inputs)
    _refuse_inputs(p, what, inputs)
    for name in files:
        f = p / name
        if f.exists() or f.is_symlink():
            write_target(f, what=f"{what} file")
            _refuse_inputs(f, f"{what} file", inputs)
        else:
            check_name_lengths(f, what=f"{what} file")
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
    """Where ``solve`` writes an interrupted result instead of ``out``: ``NAME.interrupted.json``
    (``NAME`` shortened when the whole would be longer than the file system takes)."""
    p = Path(out)
    stem = p.name[:-5] if p.name.lower().endswith(".json") else p.name
    return p.with_name(fit_name(stem, ".interrupted.json", name_max(p.parent)))
