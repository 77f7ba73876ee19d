"""An output folder holding the files of one run, named by its ``manifest.json``.

A command that writes a run of files into a folder (``selfsupport edit --out DIR``) goes through
:meth:`RunFolder.prepare`, so the files of two runs never mix without a word:

* The folder must be new or empty (the command's own input files in it aside); a folder
  holding anything else is refused unless ``force`` is given.
* With ``force``, the files an earlier run wrote there are removed first: those its manifest
  names, each only while its content still has the SHA-256 the manifest recorded (a file
  changed since is the user's). Nothing else is removed. A file the new run would write over
  that no earlier manifest vouches for is refused; the other files are kept and reported in
  :attr:`RunFolder.leftovers`.
* The manifest is rewritten (atomically) after every recorded step with ``complete: false``
  and once more at the end with ``complete: true``, so even an interrupted run's folder says
  which files are its own.

Manifest layout::

    {"format": "selfsupport-run", "version": 1, <the command's info: command, script, ...>,
     "complete": true, "stages": [{<the step's info>, "files": {"NAME": "SHA-256", ...}}, ...]}
"""
from __future__ import annotations

import hashlib
import json
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping

from selfsupport.core.errors import InputError
from selfsupport.io.atomic import atomic_write_text
from selfsupport.io.safety import check_output_dir, same_file

__all__ = ["RunFolder", "MANIFEST", "MANIFEST_FORMAT", "file_sha256"]

#: The manifest's file name inside the folder.
MANIFEST = "manifest.json"
#: The manifest's ``format`` key: how a manifest written by this module is recognised.
MANIFEST_FORMAT = "selfsupport-run"


def file_sha256(path: str | os.PathLike) -> str:
    """The SHA-256 of a file's content, hex."""
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


@dataclass
class RunFolder:
    """The folder of one run and its manifest (see the module docstring)."""

    path: Path
    info: dict[str, Any]
    stages: list[dict[str, Any]] = field(default_factory=list)
    #: Entries of the folder that are not this run's (kept; worth telling the user about).
    leftovers: tuple[str, ...] = ()

    @classmethod
    def prepare(cls, path: str | os.PathLike, files: Iterable[str], *, force: bool = False, what: str = "--out",
                inputs: Iterable[tuple[str, str | os.PathLike | None]] = (),
                info: Mapping[str, Any] | None = None) -> "RunFolder":
        """Check the folder for a run writing ``files`` into it, remove an earlier run's files
        when ``force`` (see the module docstring), and create it.

        Raises
        ------
        InputError
            The folder is not empty and ``force`` is not given; or a file the run would write
            was not written by an earlier run; or :func:`~selfsupport.io.safety.check_output_dir`
            refuses the folder or a file in it.
        """
        p = Path(path)
        files = list(files)
        ins = [(n, q) for n, q in inputs if q is not None]
        check_output_dir(p, what=what, files=[*files, MANIFEST], inputs=ins)
        present = sorted(e.name for e in os.scandir(p)) if p.is_dir() else []
        present = [n for n in present if not any(same_file(p / n, q) for _, q in ins)]
        if present and not force:
            shown = ", ".join(present[:3]) + (", ..." if len(present) > 3 else "")
            raise InputError(f"{what} {p} is not empty ({len(present)} entries: {shown}); give a new or empty "
                             "folder, or add --force to replace the files an earlier run wrote there")
        earlier = _earlier_files(p) if MANIFEST in present else None
        ours = {n for n, digest in (earlier or {}).items() if n in present and _unchanged(p / n, digest)}
        if earlier is not None:
            ours.add(MANIFEST)
        for name in [*files, MANIFEST]:
            if name in present and name not in ours:
                raise InputError(f"refusing to write {what} {p / name}: it was not written by an earlier run "
                                 f"(no {MANIFEST} there names it with its present content); move it away or "
                                 "choose another folder")
        for name in sorted(ours):
            os.unlink(p / name)
        p.mkdir(parents=True, exist_ok=True)
        return cls(path=p, info=dict(info or {}), leftovers=tuple(n for n in present if n not in ours))

    def record(self, entry: Mapping[str, Any], files: Iterable[str]) -> None:
        """Add a finished step (``entry``, e.g. a stage's index and edits) and the ``files``
        (names inside the folder) it wrote; the manifest is rewritten."""
        self.stages.append({**entry, "files": {n: file_sha256(self.path / n) for n in files}})
        self._write(complete=False)

    def finish(self) -> None:
        """Mark the run complete in the manifest."""
        self._write(complete=True)

    def _write(self, *, complete: bool) -> None:
        doc = {"format": MANIFEST_FORMAT, "version": 1, **self.info, "complete": complete, "stages": self.stages}
        atomic_write_text(self.path / MANIFEST, json.dumps(doc, indent=1, allow_nan=False) + "\n")


def _earlier_files(folder: Path) -> dict[str, str] | None:
    """The files (name -> SHA-256) an earlier run's manifest in ``folder`` names; ``None`` when
    the manifest is not a regular file this module wrote."""
    try:
        if not stat.S_ISREG(os.lstat(folder / MANIFEST).st_mode):
            return None
        doc = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("format") != MANIFEST_FORMAT or not isinstance(doc.get("stages"), list):
        return None
    out: dict[str, str] = {}
    for st in doc["stages"]:
        named = st.get("files") if isinstance(st, dict) else None
        if not isinstance(named, dict):
            continue
        for name, digest in named.items():
            # only plain names inside the folder (a manifest cannot point elsewhere)
            if (isinstance(name, str) and isinstance(digest, str) and name not in ("", ".", "..", MANIFEST)
                    and os.sep not in name and "/" not in name):
                out[name] = digest
    return out


def _unchanged(path: Path, digest: str) -> bool:
    """``path`` is a regular file (not a link) whose content has the SHA-256 ``digest``."""
    try:
        if not stat.S_ISREG(os.lstat(path).st_mode):
            return False
        return file_sha256(path) == digest
    except OSError:
        return False
