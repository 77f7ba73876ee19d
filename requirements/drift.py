"""Compare the running environment with a lock file: what ``make test-latest`` reports.

Usage: ``python requirements/drift.py requirements/test.lock``. Prints one line per package whose
installed version differs from the lock (``name  locked -> installed``) and the packages the lock
names but the environment lacks; exits 0 (the comparison is a report, the tests decide).
"""
from __future__ import annotations

import re
import sys
from importlib import metadata
from pathlib import Path

from packaging.markers import Marker

PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)(?:\[[^\]]*\])?==([^\s;#]+)\s*(?:;([^#]*))?")


def canonical(name: str) -> str:
    """PEP 503 normalised distribution name."""
    return re.sub(r"[-_.]+", "-", name).lower()


def locked(path: Path) -> dict[str, str]:
    """``{name: version}`` of every ``name==version`` line of a lock file whose environment
    marker (``; python_full_version >= '3.12'``, ``; sys_platform == 'win32'``) holds here."""
    pins = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        m = PIN.match(line.strip())
        if m and (not m.group(3) or Marker(m.group(3).strip()).evaluate()):
            pins[canonical(m.group(1))] = m.group(2)
    return pins


def main(argv: list[str]) -> int:
    if len(argv) != 1 or not Path(argv[0]).is_file():
        print("usage: python requirements/drift.py LOCKFILE", file=sys.stderr)
        return 2
    pins = locked(Path(argv[0]))
    installed = {canonical(d.metadata["Name"]): d.version for d in metadata.distributions()}
    changed = sorted((n, v, installed[n]) for n, v in pins.items() if n in installed and installed[n] != v)
    missing = sorted(n for n in pins if n not in installed)
    print(f"{len(changed)} of {len(pins)} locked packages differ from {argv[0]}:")
    for name, old, new in changed:
        print(f"  {name:28s} {old} -> {new}")
    for name in missing:
        print(f"  {name:28s} {pins[name]} -> (not installed here)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
