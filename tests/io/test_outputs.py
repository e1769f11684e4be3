"""Output folders: a stage sub-folder written by bayescal may be replaced with force."""

import json

import pytest

from bayescal.errors import UsageError
from bayescal.io.outputs import MANIFEST, OutputFolder, check_out


def test_stage_folder_listed_in_the_parent_manifest_may_be_replaced(tmp_path):
    out = tmp_path / "out"
    (out / "image").mkdir(parents=True)
    (out / "image" / "report.md").write_text("x")
    (out / MANIFEST).write_text(json.dumps({"written_by": "bayescal",
                                            "files": ["image/report.md"]}))
    assert check_out(out / "image", force=True) == out / "image"
    with pytest.raises(UsageError, match="pass --force"):
        check_out(out / "image", force=False)
    # a sub-folder the manifest does not list is not bayescal's
    (out / "mine").mkdir()
    (out / "mine" / "notes.txt").write_text("x")
    with pytest.raises(UsageError, match="not written by bayescal"):
        check_out(out / "mine", force=True)


def _stage(folder, files):
    for name, text in files.items():
        p = folder.path / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
        folder.add(p)


def test_ctrl_c_during_a_merge_is_held_until_every_file_is_in_place(tmp_path, monkeypatch):
    """A SIGINT while --force merges into an old folder never leaves it half new, half old."""
    import os
    import signal

    import bayescal.io.outputs as outputs

    out = tmp_path / "out"
    with OutputFolder(out) as folder:
        _stage(folder, {"a.txt": "old a", "b.txt": "old b", "c.txt": "old c"})
    replace, calls = os.replace, []

    def replace_then_interrupt(src, dst):
        replace(src, dst)
        calls.append(dst)
        if len(calls) == 1:                               # after the first of three files
            os.kill(os.getpid(), signal.SIGINT)

    monkeypatch.setattr(outputs.os, "replace", replace_then_interrupt)
    handler = signal.getsignal(signal.SIGINT)
    try:
        with pytest.warns(RuntimeWarning, match="held back until they were all in place"):
            with OutputFolder(out) as folder:
                _stage(folder, {"a.txt": "new a", "b.txt": "new b", "c.txt": "new c"})
    except KeyboardInterrupt:
        pytest.fail("the Ctrl-C escaped in the middle of the merge")
    assert folder.committed
    assert [(out / f).read_text() for f in ("a.txt", "b.txt", "c.txt")] == ["new a", "new b",
                                                                           "new c"]
    assert signal.getsignal(signal.SIGINT) is handler    # the caller's handler is back
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_an_interrupt_before_the_commit_leaves_the_old_folder_untouched(tmp_path):
    out = tmp_path / "out"
    with OutputFolder(out) as folder:
        _stage(folder, {"a.txt": "old a"})
    with pytest.raises(KeyboardInterrupt):
        with OutputFolder(out) as folder:
            _stage(folder, {"a.txt": "new a"})
            raise KeyboardInterrupt
    assert not folder.committed and (out / "a.txt").read_text() == "old a"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_the_messages_suggest_what_works(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("x")
    (tmp_path / "mine-2").mkdir()
    for force in (False, True):       # not bayescal's: --force would be refused, so not offered
        with pytest.raises(UsageError, match=r"--force or not: choose a new or empty folder, "
                                             r"e\.g\. --out .*mine-3") as err:
            check_out(mine, force=force)
        assert "pass --force" not in str(err.value)
    run = tmp_path / "run"
    run.mkdir()
    (run / "result.json").write_text("{}")
    (run / MANIFEST).write_text(json.dumps({"written_by": "bayescal", "files": ["result.json"]}))
    with pytest.raises(UsageError, match=r"holds an earlier bayescal run; pass --force to replace "
                                         r"it, or choose another --out, e\.g\. .*run-2"):
        check_out(run, force=False)
