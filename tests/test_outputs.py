"""Files the program did not create: a read-only output is refused, a name at the file system's
limit is written (and one over it refused before any solve), a SIGTERM during a write leaves no
temporary file, and ``edit --out DIR`` keeps its runs apart (fresh folder or ``--force``, a
manifest naming the run's files, never removing a file it did not write)."""
from __future__ import annotations

import hashlib
import json
import os
import pwd
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from selfsupport import api, cli
from selfsupport.core.errors import InputError
from selfsupport.io.atomic import atomic_write_text
from selfsupport.io.safety import interrupted_path
from tests.test_cli import assert_one_line_error


def _no_solve(monkeypatch) -> None:
    monkeypatch.setattr(api, "solve", lambda *a, **k: pytest.fail("solved although the output is unwritable"))


def _name_max(directory: Path) -> int:
    return os.pathconf(directory, "PC_NAME_MAX")


# ------------------------------------------------------------------------------ read-only targets
def test_a_read_only_out_is_refused_before_solving_and_left_untouched(tmp_path, capsys, monkeypatch):
    out = tmp_path / "net.json"
    out.write_text("precious")
    out.chmod(0o444)
    _no_solve(monkeypatch)
    rc = cli.main(["solve", "shape:dome:100", "--out", str(out)])
    assert_one_line_error(capsys.readouterr().err, rc, 2, needle="read-only")
    assert out.read_text() == "precious" and (out.stat().st_mode & 0o777) == 0o444
    assert os.listdir(tmp_path) == ["net.json"]


def test_the_refusal_names_the_file_and_the_fix(tmp_path):
    out = tmp_path / "net.json"
    out.write_text("precious")
    out.chmod(0o444)
    with pytest.raises(InputError) as e:
        atomic_write_text(out, "new")
    assert str(out) in str(e.value) and "chmod" in str(e.value) and "another name" in str(e.value)
    assert out.read_text() == "precious"


def test_a_file_the_user_may_not_write_is_refused_for_a_non_root_user(tmp_path):
    """A file the user has no write permission on (owned by someone else), in a folder the user
    may write: the rename would replace it; as ``cp`` does, the write is refused instead."""
    work = tmp_path / "shared"
    work.mkdir()
    work.chmod(0o777)
    out = work / "net.json"
    out.write_text("precious")
    if os.geteuid() != 0:  # (not root: the user's own file made read-only shows the same refusal)
        out.chmod(0o444)
        with pytest.raises(InputError, match="read-only"):
            atomic_write_text(out, "new")
        assert out.read_text() == "precious"
        return
    out.chmod(0o644)  # root's, writable by root only
    nobody = pwd.getpwnam("nobody")
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: become nobody inside the folder (relative paths: no search of the parents needed)
        code = 3
        try:
            os.close(r)
            os.chdir(work)
            os.setgid(nobody.pw_gid)
            os.setuid(nobody.pw_uid)
            try:
                atomic_write_text("net.json", "new")
                code = 1
            except InputError as e:
                os.write(w, str(e).encode())
                code = 0
        finally:
            os._exit(code)
    os.close(w)
    message = os.read(r, 4096).decode()
    os.close(r)
    _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0, "a user without write permission replaced the file"
    assert "net.json" in message and "not writable" in message
    assert out.read_text() == "precious" and out.stat().st_uid == 0
    assert os.listdir(work) == ["net.json"]


# -------------------------------------------------------------------------------- long names
@pytest.mark.parametrize("extra", [0, 8, 17], ids=["at-limit", "limit-8", "limit-17"])
def test_a_name_up_to_the_file_system_limit_is_written(tmp_path, extra):
    name = "n" * (_name_max(tmp_path) - extra - 5) + ".json"
    target = tmp_path / name
    atomic_write_text(target, "content")
    assert target.read_text() == "content"
    assert os.listdir(tmp_path) == [name]


def test_a_multibyte_name_at_the_limit_is_written(tmp_path):
    name = "\u00e9" * ((_name_max(tmp_path) - 5) // 2) + ".json"  # two bytes each in UTF-8
    atomic_write_text(tmp_path / name, "content")
    assert (tmp_path / name).read_text() == "content"
    assert os.listdir(tmp_path) == [name]


@pytest.mark.parametrize("where", ["new-folder", "existing-folder", "folder-name"])
def test_a_name_over_the_limit_is_refused_before_solving(tmp_path, capsys, monkeypatch, where):
    long = "n" * (_name_max(tmp_path) + 1)
    out = {"new-folder": tmp_path / "new" / f"{long}.json", "existing-folder": tmp_path / f"{long}.json",
           "folder-name": tmp_path / "new" / long / "net.json"}[where]
    _no_solve(monkeypatch)
    rc = cli.main(["solve", "shape:dome:100", "--out", str(out)])
    assert_one_line_error(capsys.readouterr().err, rc, 2, needle="too long")
    assert os.listdir(tmp_path) == []


def test_a_report_folder_over_the_limit_is_refused_before_solving(tmp_path, capsys, monkeypatch):
    _no_solve(monkeypatch)
    report = tmp_path / "new" / ("r" * (_name_max(tmp_path) + 1))
    rc = cli.main(["solve", "shape:dome:100", "--out", str(tmp_path / "net.json"), "--report", str(report)])
    assert_one_line_error(capsys.readouterr().err, rc, 2, needle="too long")
    assert os.listdir(tmp_path) == []


def test_the_interrupted_name_of_a_long_out_stays_within_the_limit(tmp_path):
    limit = _name_max(tmp_path)
    out = tmp_path / ("n" * (limit - 5) + ".json")
    p = interrupted_path(out)
    assert p.parent == tmp_path and p.name.endswith(".interrupted.json")
    assert len(os.fsencode(p.name)) <= limit
    assert interrupted_path(tmp_path / "net.json").name == "net.interrupted.json"


# ------------------------------------------------------------------------------------- SIGTERM
SLOW_WRITE = """
import sys, time
import selfsupport.io.network_json as nj
from selfsupport import cli
from selfsupport.io.atomic import atomic_write_text

def slow(path, text, **kw):  # a large network written slowly: SIGTERM arrives mid-write
    def chunks():
        yield "x" * 4_000_000
        while True:
            time.sleep(0.02)
            yield "x" * 1000
    atomic_write_text(path, chunks(), **kw)

nj.atomic_write_text = slow
sys.exit(cli.main(["solve", "shape:dome:100", "--out", sys.argv[1], "--quiet"]))
"""


def test_sigterm_during_a_write_removes_the_temporary_file_and_keeps_the_target(tmp_path):
    out = tmp_path / "net.json"
    out.write_text("precious")
    p = subprocess.Popen([sys.executable, "-c", SLOW_WRITE, str(out)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not [q for q in tmp_path.iterdir() if q.name.endswith(".tmp")]:
            assert p.poll() is None, p.communicate()
            assert time.monotonic() < deadline, "the write never started"
            time.sleep(0.02)
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == cli.EXIT_CODES["interrupted"], (p.returncode, err)
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1 and "interrupted" in err
    assert os.listdir(tmp_path) == ["net.json"]
    assert out.read_text() == "precious"


def test_the_cli_restores_the_sigterm_handler_it_installed(tmp_path, monkeypatch):
    before = signal.getsignal(signal.SIGTERM)
    seen = []
    monkeypatch.setattr(api, "solve", lambda *a, **k: seen.append(signal.getsignal(signal.SIGTERM)) or 1 / 0)
    cli.main(["solve", "shape:dome:100", "--out", str(tmp_path / "n.json")])
    assert seen and seen[0] not in (signal.SIG_DFL, before)
    assert signal.getsignal(signal.SIGTERM) == before


# ---------------------------------------------------------------------------------- edit --out DIR
EDIT_START = """
[start]
scene = "shape:barrel_vault:150"
"""
RAISE = """
[[edit]]
op = "raise"
select = {{ nearest = [{x}, 0.5], relative = true }}
by = 0.02
"""


def _script(tmp_path: Path, name: str, n_edits: int) -> Path:
    p = tmp_path / name
    p.write_text(EDIT_START + "".join(RAISE.format(x=0.3 + 0.1 * k) for k in range(n_edits)))
    return p


def _manifest(folder: Path) -> dict:
    return json.loads((folder / "manifest.json").read_text())


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def test_edit_writes_a_manifest_naming_the_run_and_its_stages(tmp_path):
    script = _script(tmp_path, "three.toml", 2)
    out = tmp_path / "run"
    assert cli.main(["edit", str(script), "--out", str(out), "--no-figures"]) == 0
    m = _manifest(out)
    assert m["script"] == str(script) and m["script_sha256"] == _sha(script)
    assert [s["index"] for s in m["stages"]] == [0, 1, 2] and m["complete"] is True
    assert [s["edits"] for s in m["stages"]] == [[], ["raise"], ["raise"]]
    written = {n for s in m["stages"] for n in s["files"]}
    assert written == {"stage-00.json", "stage-01.json", "stage-02.json"}
    assert sorted(os.listdir(out)) == sorted(written | {"manifest.json"})
    for s in m["stages"]:
        for name, digest in s["files"].items():
            assert _sha(out / name) == digest
            assert json.loads((out / name).read_text())["stage"]["index"] == s["index"]


def test_edit_refuses_a_folder_that_is_not_empty_without_force(tmp_path, capsys, monkeypatch):
    import selfsupport.design.script as script_mod

    out = tmp_path / "run"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    monkeypatch.setattr(script_mod, "replay", lambda *a, **k: pytest.fail("replayed into a used folder"))
    rc = cli.main(["edit", str(_script(tmp_path, "s.toml", 1)), "--out", str(out), "--no-figures"])
    assert_one_line_error(capsys.readouterr().err, rc, 2, needle="--force")
    assert os.listdir(out) == ["notes.txt"] and (out / "notes.txt").read_text() == "mine"


def test_edit_force_replaces_only_the_files_the_earlier_run_wrote(tmp_path, capsys):
    out = tmp_path / "run"
    assert cli.main(["edit", str(_script(tmp_path, "long.toml", 3)), "--out", str(out), "--no-figures"]) == 0
    (out / "notes.txt").write_text("mine")
    edited = out / "stage-03.json"  # a stage file changed by the user after the run: no longer the program's
    edited.write_text(edited.read_text().replace('"stage"', '"stage" ', 1))
    capsys.readouterr()
    short = _script(tmp_path, "short.toml", 1)
    assert cli.main(["edit", str(short), "--out", str(out), "--no-figures", "--force"]) == 0
    err = capsys.readouterr().err
    # the earlier run's untouched stage files are gone, the user's files stay (and are pointed out)
    assert sorted(os.listdir(out)) == ["manifest.json", "notes.txt", "stage-00.json", "stage-01.json",
                                       "stage-03.json"]
    assert (out / "notes.txt").read_text() == "mine" and '"stage" ' in edited.read_text()
    assert "stage-03.json" in err and "notes.txt" in err
    m = _manifest(out)
    assert m["script_sha256"] == _sha(short)
    assert [n for s in m["stages"] for n in s["files"]] == ["stage-00.json", "stage-01.json"]


def test_edit_force_never_writes_over_a_file_it_did_not_write(tmp_path, capsys, monkeypatch):
    import selfsupport.design.script as script_mod

    out = tmp_path / "run"
    out.mkdir()
    (out / "stage-00.json").write_text("the user's own")
    monkeypatch.setattr(script_mod, "replay", lambda *a, **k: pytest.fail("replayed over a foreign file"))
    rc = cli.main(["edit", str(_script(tmp_path, "s.toml", 1)), "--out", str(out), "--no-figures", "--force"])
    assert_one_line_error(capsys.readouterr().err, rc, 2, needle="stage-00.json")
    assert os.listdir(out) == ["stage-00.json"] and (out / "stage-00.json").read_text() == "the user's own"
