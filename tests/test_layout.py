"""The package's import rules (docs/development/design.md, "Layers"): the project's own modules are
imported at the top of a module, outside the command line's command modules; every module imports
on its own (no cycle hidden behind a function-level import)."""
from __future__ import annotations

import ast
import importlib
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import formulations
import selfsupport
from selfsupport import api

ROOT = Path(__file__).resolve().parents[1]
PROJECT = ("selfsupport", "formulations")
#: Where a function-level import of the project is deliberate: the command line's parser and
#: shared helpers (every run imports them, ``selfsupport --help`` too) import the layers when
#: called; the method choice loads the multilevel machinery only for a mesh large enough to use
#: it (0.5 s of imports). The other command modules, imported only when their command runs,
#: import their layer at the top.
LAZY_ALLOWED = (ROOT / "selfsupport" / "cli" / "common.py", ROOT / "selfsupport" / "cli" / "__init__.py",
                ROOT / "selfsupport" / "methods" / "choice.py")
#: Files that import the modules they name where used (a plain solve does not load them).
LAZY_NAMED = {ROOT / "selfsupport" / "api.py": api._LAZY}


def _sources() -> list[Path]:
    return sorted(p for pkg in PROJECT for p in (ROOT / pkg).rglob("*.py"))


def _function_level_project_imports(path: Path) -> list[str]:
    """``file:line: statement`` of every import of a project module inside a function or class
    (an ``if TYPE_CHECKING`` block excepted)."""
    tree = ast.parse(path.read_text())
    module_level: set[int] = set()

    def collect(stmts: list[ast.stmt]) -> None:  # the module's body and its top-level if/try blocks
        for s in stmts:
            module_level.add(id(s))
            if isinstance(s, (ast.If, ast.Try)):
                for block in (s.body, s.orelse, getattr(s, "finalbody", []),
                              *[h.body for h in getattr(s, "handlers", [])]):
                    collect(block)

    collect(tree.body)
    skip = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
            for n in ast.walk(node)}
    found = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.Import, ast.ImportFrom)) and id(node) not in module_level and id(node) not in skip:
            names = [node.module or ""] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names]
            if any(n.split(".")[0] in PROJECT for n in names):
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}: {ast.unparse(node)}")
    return found


def test_project_imports_sit_at_the_top_of_their_modules():
    offenders = [hit for p in _sources() if p.name != "__main__.py" and not any(p.is_relative_to(a) for a in LAZY_ALLOWED)
                 for hit in _function_level_project_imports(p)
                 if not any(f": from {m} import " in hit for m in LAZY_NAMED.get(p, ()))]
    assert offenders == [], "import these at the top of the module:\n" + "\n".join(offenders)


def test_the_checker_finds_a_function_level_import():
    """The rule above can fail: a project import inside a function is reported, one at the top is not."""
    f = ROOT / "selfsupport" / "_probe_for_test_layout.py"
    assert not f.exists()
    try:
        f.write_text("from selfsupport.core.mesh import PolyMesh\n\n\ndef g():\n"
                     "    from selfsupport.core.geometry import bbox_diagonal\n    return bbox_diagonal\n")
        hits = _function_level_project_imports(f)
    finally:
        f.unlink()
    assert len(hits) == 1 and "bbox_diagonal" in hits[0] and ":5:" in hits[0]


def _modules() -> list[str]:
    names = []
    for pkg in (selfsupport, formulations):
        names.append(pkg.__name__)
        names += [m.name for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + ".")
                  if not m.name.endswith("__main__")]
    return names


@pytest.mark.parametrize("layer", ["selfsupport.core", "formulations", "selfsupport.io", "selfsupport.analysis",
                                   "selfsupport.methods", "selfsupport.structure", "selfsupport.remesh",
                                   "selfsupport.design", "selfsupport.api"])
def test_every_module_of_a_layer_imports_alone_in_a_fresh_interpreter(layer):
    """A cycle at import time shows as a partly initialised module when a module is imported first."""
    mods = [m for m in _modules() if m == layer or m.startswith(layer + ".")]
    assert mods
    code = ("import importlib, sys\nbad = []\n"
            f"for m in {mods!r}:\n"
            "    for k in [k for k in sys.modules if k.startswith(('selfsupport', 'formulations'))]:\n"
            "        del sys.modules[k]\n"
            "    try:\n        importlib.import_module(m)\n"
            "    except Exception as e:\n        bad.append(f'{m}: {e!r}')\n"
            "print('\\n'.join(bad))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "", out.stdout


def test_the_layers_contract_names_every_package():
    """Every subpackage of selfsupport is placed in the import-linter layers (a new package must be)."""
    import tomllib

    conf = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    layers = next(c for c in conf["contracts"] if c["type"] == "layers")["layers"]
    named = {name.strip() for row in layers for name in row.replace(":", "|").split("|")}
    packages = {f"selfsupport.{m.name}" for m in pkgutil.iter_modules(selfsupport.__path__)
                if m.ispkg or m.name == "api"}
    assert packages - named == set(), f"not in any layer: {sorted(packages - named)}"
    assert importlib.util.find_spec("importlinter") is not None  # make lint's checker is installed
