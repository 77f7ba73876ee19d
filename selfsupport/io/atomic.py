"""Atomic file writes: a reader never sees a half-written file.

The data goes to a temporary file in the target's directory (same file system, so the final
``os.replace`` is an atomic rename), is flushed and fsync'ed, then renamed over the target.
If anything fails on the way — including an exception raised by a chunk generator while the
content is still being produced, and a ``KeyboardInterrupt`` (Ctrl-C, or SIGTERM through the
CLI's handler) — the temporary file is removed and an existing target is left untouched. The
temporary name, ``.NAME.HEX.tmp``, shortens ``NAME`` as needed to stay within the file system's
``NAME_MAX``, so any name the file system takes can be written.

What may be written is decided by :func:`selfsupport.io.safety.write_target`: a regular file the
user may write or a new path; a symlink is written through to its target (the link stays a
link); a directory, device, FIFO, socket or read-only file is refused with an
:class:`~selfsupport.core.errors.InputError`.
"""
from __future__ import annotations

import os
import secrets
from pathlib import Path
from typing import Iterable

from selfsupport.core.errors import InputError
from selfsupport.io.safety import fit_name, name_max, write_target

__all__ = ["atomic_write_text", "atomic_write_bytes"]


def atomic_write_text(path: str | os.PathLike, text: str | Iterable[str], *, encoding: str = "utf-8") -> None:
    """Write ``text`` (a string or an iterable of string chunks) to ``path`` atomically.

    Parameters
    ----------
    path
        Target file; missing parent directories are created.
    text
        The content, or chunks of it (streamed, so large outputs need not be joined first).
    encoding
        Text encoding, UTF-8 by default. Newlines are written as given (no translation).
    """
    if isinstance(text, str):
        chunks: Iterable[bytes] = (text.encode(encoding),)
    else:
        chunks = (c.encode(encoding) for c in text)
    _atomic_write(Path(path), chunks)


def atomic_write_bytes(path: str | os.PathLike, data: bytes | Iterable[bytes]) -> None:
    """Write ``data`` (bytes or an iterable of byte chunks) to ``path`` atomically."""
    if isinstance(data, (bytes, bytearray, memoryview)):
        chunks: Iterable[bytes] = (bytes(data),)
    else:
        chunks = data
    _atomic_write(Path(path), chunks)


def _atomic_write(path: Path, chunks: Iterable[bytes]) -> None:
    path = write_target(path)
    parent = path.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"cannot create directory {parent} for {path}: {e.strerror or e}; "
                         "check the path and permissions") from e
    # Keep an existing file's permission bits; for a new file let the umask decide (0o666 & ~umask),
    # as a plain open() would — mkstemp's 0o600 would surprise users.
    try:
        mode = path.stat().st_mode & 0o7777
    except OSError:
        mode = 0o666
    fd, tmp = _create_temp(parent, path.name, mode)
    try:
        with os.fdopen(fd, "wb") as f:
            for chunk in chunks:
                f.write(chunk)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(e, OSError):
            raise InputError(f"cannot write {path}: {e.strerror or e}; check the path, free space and permissions") from e
        raise
    _fsync_dir(parent)


def _create_temp(parent: Path, name: str, mode: int) -> tuple[int, Path]:
    limit = name_max(parent)
    for _ in range(100):
        tmp = parent / fit_name(f".{name}", f".{secrets.token_hex(6)}.tmp", limit)
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), mode), tmp
        except FileExistsError:
            continue
        except OSError as e:
            raise InputError(f"cannot write into {parent}: {e.strerror or e}; check the path and permissions") from e
    raise InputError(f"cannot create a temporary file in {parent}; remove stale .{name[:20]}*.tmp files")


def _fsync_dir(directory: Path) -> None:
    """Make the rename itself durable (best effort: not every platform can open a directory)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
