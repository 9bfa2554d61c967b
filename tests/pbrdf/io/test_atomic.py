"""Atomic writes: temporary sibling names and the targets they belong to."""

from pbrdf.io.atomic import temporary_path, temporary_target


def test_temporary_names(tmp_path):
    tmp = temporary_path(tmp_path / "000001.exr")
    assert tmp.parent == tmp_path
    assert temporary_target(tmp.name) == "000001.exr"
    assert temporary_target(".000001_raw.old-12-0123abcd") == "000001_raw"  # pbrdf.data.capture's set-aside folders
    assert temporary_target("000001.exr") is None
    assert temporary_path(tmp_path / "a.exr") != temporary_path(tmp_path / "a.exr")
