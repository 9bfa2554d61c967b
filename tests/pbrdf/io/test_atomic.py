"""Atomic writes: temporary sibling names, the targets they belong to, removal of a killed writer's leftovers."""

import os
import subprocess
import sys
import time

import pytest

from pbrdf.io.atomic import remove_leftovers, temporary_path, temporary_target


def test_temporary_names(tmp_path):
    tmp = temporary_path(tmp_path / "000001.exr")
    assert tmp.parent == tmp_path
    assert temporary_target(tmp.name) == "000001.exr"
    assert temporary_target(".000001_raw.old-12-0123abcd") == "000001_raw"  # pbrdf.data.capture's set-aside folders
    assert temporary_target("000001.exr") is None
    assert temporary_path(tmp_path / "a.exr") != temporary_path(tmp_path / "a.exr")


DEAD = 999_999_999  # above any pid_max: no process has it


def _plant(folder, names):
    for name in names:
        if name.endswith("/"):
            (folder / name.rstrip("/")).mkdir()
            (folder / name.rstrip("/") / "part").write_bytes(b"x")
        else:
            (folder / name).write_bytes(b"x")


def test_remove_leftovers_takes_only_dead_writers_temporaries(tmp_path):
    leftovers = [f".model.pt.tmp-{DEAD}-0a1b2c3d", f".log.csv.tmp-{DEAD}-89abcdef", f".000001_raw.tmp-{DEAD}-0123abcd/"]
    kept = [
        "model.pt",
        "notes.txt",
        ".model.pt.tmp",  # not the writer's pattern
        f"model.pt.tmp-{DEAD}-0a1b2c3d",  # no leading dot
        f".model.pt.tmp-{DEAD}-0A1B2C3D",  # upper-case hex
        f".model.pt.tmp-{DEAD}-0a1b2c3",  # 7 hex digits
        f".000002_raw.old-{DEAD}-0123abcd",  # a previous version set aside: maybe the only copy
        f".model.pt.tmp-{os.getpid()}-0a1b2c3d",  # this process's own write in progress
    ]
    _plant(tmp_path, leftovers + kept)
    removed = remove_leftovers(tmp_path)
    assert sorted(p.name for p in removed) == sorted(n.rstrip("/") for n in leftovers)
    assert sorted(os.listdir(tmp_path)) == sorted(kept)
    assert remove_leftovers(tmp_path / "missing") == []


def test_remove_leftovers_of_some_targets_only(tmp_path):
    _plant(tmp_path, [f".model.pt.tmp-{DEAD}-0a1b2c3d", f".other.bin.tmp-{DEAD}-0a1b2c3d"])
    assert [p.name for p in remove_leftovers(tmp_path, {"model.pt"})] == [f".model.pt.tmp-{DEAD}-0a1b2c3d"]
    assert [p.name for p in remove_leftovers(tmp_path, lambda t: t.endswith(".csv"))] == []
    assert os.listdir(tmp_path) == [f".other.bin.tmp-{DEAD}-0a1b2c3d"]


def test_a_live_writer_keeps_its_temporary_and_a_killed_one_loses_it(tmp_path):
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        name = f".manifest.json.tmp-{proc.pid}-0a1b2c3d"
        (tmp_path / name).write_text("{")
        assert remove_leftovers(tmp_path) == []  # still running: its write may be in progress
        proc.kill()
        if sys.platform.startswith("linux"):  # killed, not yet waited for: a zombie, whose writes are over
            time.sleep(0.2)
            assert [p.name for p in remove_leftovers(tmp_path)] == [name]
    finally:
        proc.wait()
    remove_leftovers(tmp_path)
    assert os.listdir(tmp_path) == []


class TestAtomicFolder:
    """atomic_folder: a folder's files appear together on success; a failure leaves neither the target nor a temp."""

    def test_failure_leaves_nothing(self, tmp_path):
        from pbrdf.io.atomic import atomic_folder

        target = tmp_path / "capture"
        try:
            with atomic_folder(target) as staging:
                (staging / "raw_0.png").write_bytes(b"half")
                raise OSError("disk full (simulated)")
        except OSError:
            pass
        assert os.listdir(tmp_path) == []

    def test_existing_target_is_replaced_only_on_success(self, tmp_path):
        from pbrdf.io.atomic import atomic_folder

        target = tmp_path / "capture"
        target.mkdir()
        (target / "old.txt").write_text("old")
        try:
            with atomic_folder(target) as staging:
                (staging / "new.txt").write_text("new")
                raise KeyboardInterrupt
        except KeyboardInterrupt:
            pass
        assert os.listdir(tmp_path) == ["capture"] and os.listdir(target) == ["old.txt"]
        with atomic_folder(target) as staging:
            (staging / "new.txt").write_text("new")
            assert os.listdir(target) == ["old.txt"]  # nothing visible before the block ends
        assert os.listdir(tmp_path) == ["capture"] and os.listdir(target) == ["new.txt"]

    def test_merge_adds_files_and_keeps_the_others(self, tmp_path):
        from pbrdf.io.atomic import atomic_folder

        out = tmp_path / "o" / "deep"
        with atomic_folder(out, merge=True) as staging:
            (staging / "a_normal.exr").write_bytes(b"1")
            assert not out.exists()  # created only when the files are ready
        (out / "keep.txt").write_text("x")
        with atomic_folder(out, merge=True) as staging:
            (staging / "a_normal.exr").write_bytes(b"2")
            (staging / "b_normal.exr").write_bytes(b"3")
        assert sorted(os.listdir(out)) == ["a_normal.exr", "b_normal.exr", "keep.txt"]
        assert (out / "a_normal.exr").read_bytes() == b"2"
        assert os.listdir(out.parent) == ["deep"]  # no staging folder left
        with pytest.raises(ValueError), atomic_folder(out, merge=True) as staging:
            (staging / "c_normal.exr").write_bytes(b"4")
            raise ValueError("bad map")
        assert sorted(os.listdir(out)) == ["a_normal.exr", "b_normal.exr", "keep.txt"]

    def test_a_file_in_the_way_is_refused(self, tmp_path):
        from pbrdf.io.atomic import atomic_folder

        (tmp_path / "out").write_text("x")
        with pytest.raises(NotADirectoryError, match="exists and is not a folder"), atomic_folder(tmp_path / "out"):
            pass
        assert os.listdir(tmp_path) == ["out"]
