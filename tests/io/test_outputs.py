"""Output folders: a stage sub-folder written by bayescal may be replaced with force."""

import json

import pytest

from bayescal.errors import UsageError
from bayescal.io.outputs import MANIFEST, check_out


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
