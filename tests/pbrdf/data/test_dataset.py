"""Dataset folders: completeness, cleanup, shards, resume and the manifest."""

import json
import logging
import os

import pytest

from pbrdf.data.dataset import (
    MANIFEST_JSON,
    cleanup_partial,
    completed_indices,
    parse_shard,
    plan_work,
    read_manifest,
    remove_manifest_leftovers,
    shard_indices,
    write_manifest,
)
from pbrdf.data.sample import read_sample, sample_paths, write_sample
from tests.helpers import H, W, assert_samples_equal, make_sample


def _write_many(root, rng, indices, **kw):
    for i in indices:
        write_sample(root, i, *make_sample(rng, **kw))


def test_completed_indices_skips_orphans_and_bad_sidecars(tmp_path, rng, caplog):
    _write_many(tmp_path, rng, range(5))
    sample_paths(tmp_path, 1).sidecar.unlink()  # orphan EXR
    side = sample_paths(tmp_path, 2).sidecar
    data = json.loads(side.read_text())
    data["sha256"] = "0" * 64
    side.write_text(json.dumps(data))  # sha does not match
    sample_paths(tmp_path, 3).sidecar.write_text("{ not json")  # corrupt sidecar
    with caplog.at_level(logging.WARNING, logger="pbrdf.data.dataset"):
        assert completed_indices(tmp_path) == {0, 4}
    text = caplog.text
    assert "sample 2 is incomplete" in text and "sha256 does not match" in text
    assert "sample 3 is incomplete" in text and "invalid JSON" in text
    assert "sample 1" not in text  # a missing sidecar is the normal state of an unfinished sample
    assert completed_indices(tmp_path, shard=(0, 2)) == {0, 4}
    assert completed_indices(tmp_path, shard=(1, 2)) == set()
    assert completed_indices(tmp_path / "nothing") == set()
    with pytest.raises(ValueError, match="sha256 does not match"):
        read_sample(tmp_path, 2, verify=True)
    with pytest.raises(FileNotFoundError, match="sidecar not found"):
        read_sample(tmp_path, 1)


def test_cleanup_partial(tmp_path, rng):
    _write_many(tmp_path, rng, range(4))
    folder = tmp_path / "samples"
    sample_paths(tmp_path, 1).sidecar.unlink()  # orphan EXR
    (folder / ".000002.exr.tmp-99-0123abcd").write_bytes(b"partial")  # temp file of a complete sample
    (folder / ".000005.json.tmp-99-0123abcd").write_text("{")  # temp sidecar, no sample
    (folder / ".000007_raw.tmp-99-89abcdef").mkdir()  # temp capture folder
    (folder / "notes.txt").write_text("kept")
    side = sample_paths(tmp_path, 3).sidecar
    side.write_text(side.read_text().replace('"exr_bytes": ', '"exr_bytes": 1'))  # wrong size

    removed = cleanup_partial(tmp_path, shard=(1, 2))  # odd indices only
    assert [p.name for p in removed] == [
        ".000005.json.tmp-99-0123abcd",
        ".000007_raw.tmp-99-89abcdef",
        "000001.exr",
        "000003.exr",
        "000003.json",
    ]
    assert (folder / ".000002.exr.tmp-99-0123abcd").exists()
    removed = cleanup_partial(tmp_path)
    assert [p.name for p in removed] == [".000002.exr.tmp-99-0123abcd"]
    assert sorted(os.listdir(folder)) == ["000000.exr", "000000.json", "000002.exr", "000002.json", "notes.txt"]
    assert completed_indices(tmp_path) == {0, 2}


def test_shard_indices_partition_range():
    for count in range(14):
        for n in range(1, 6):
            parts = [shard_indices(count, (k, n)) for k in range(n)]
            assert parts == [shard_indices(count, (k, n)) for k in range(n)]  # deterministic
            flat = [i for p in parts for i in p]
            assert sorted(flat) == list(range(count))  # union is range(count), no index twice
            assert all(p == sorted(p) and all(i % n == k for i in p) for k, p in enumerate(parts))
    assert shard_indices(10, (1, 3)) == [1, 4, 7]
    for bad in [(2, 2), (-1, 2), (0, 0), (True, 2), (0.5, 2), (1,), "0/2"]:
        with pytest.raises(ValueError, match="shard"):
            shard_indices(10, bad)
    with pytest.raises(ValueError, match="count must be an integer >= 0"):
        shard_indices(-1, (0, 1))


def test_parse_shard():
    assert parse_shard("0/4") == (0, 4)
    assert parse_shard(" 3 / 4 ") == (3, 4)
    for bad in ["4/4", "a/b", "1", "1/0", "-1/3", "1/2/3", ""]:
        with pytest.raises(ValueError, match="shard"):
            parse_shard(bad)
    with pytest.raises(ValueError, match=r"'K/N'"):
        parse_shard(None)


def test_plan_work(tmp_path, rng):
    root = tmp_path / "ds"
    assert plan_work(root, 6) == list(range(6))  # no folder yet
    assert plan_work(root, 6, (1, 2)) == [1, 3, 5]
    _write_many(root, rng, [0, 2])
    with pytest.raises(FileExistsError, match=r"ds: already holds files of 2 sample\(s\).*pass --resume"):
        plan_work(root, 6)
    with pytest.raises(FileExistsError, match="--resume"):
        plan_work(root, 6, (0, 2))
    assert plan_work(root, 6, (1, 2)) == [1, 3, 5]  # another shard may share the folder
    assert plan_work(root, 6, resume=True) == [1, 3, 4, 5]
    assert plan_work(root, 6, (0, 2), resume=True) == [4]
    with pytest.raises(ValueError, match="shard"):
        plan_work(root, 6, (2, 2))


def test_killed_run_resumes_exactly_the_broken_samples(tmp_path, rng):
    root = tmp_path / "ds"
    todo = plan_work(root, 5)
    _write_many(root, rng, todo)
    sample_paths(root, 1).sidecar.unlink()  # killed before the sidecar
    exr = sample_paths(root, 3).exr
    exr.write_bytes(exr.read_bytes()[: exr.stat().st_size // 2])  # EXR damaged afterwards
    (root / "samples" / ".000004.exr.tmp-7-00ff00ff").write_bytes(b"x")  # killed mid-write of a rewrite
    assert plan_work(root, 5, resume=True) == [1, 3]
    assert plan_work(root, 5, resume=True, verify_hash=False) == [1, 3]  # the size check catches it too

    fresh = {}
    for i in plan_work(root, 5, resume=True):
        fresh[i], meta = make_sample(rng)
        write_sample(root, i, fresh[i], meta)  # overwrites the leftovers
    assert plan_work(root, 5, resume=True) == []
    assert completed_indices(root) == set(range(5))
    for i, sample in fresh.items():
        assert_samples_equal(read_sample(root, i, verify=True)[0], sample)


def test_manifest(tmp_path, rng):
    _write_many(tmp_path, rng, [0, 2, 1])
    sample_paths(tmp_path, 2).sidecar.unlink()
    info = {"count": 3, "resolution": [H, W], "seed": 7, "shard": [0, 1], "config": {"spp": 64}}
    path = write_manifest(tmp_path, info)
    assert path == tmp_path / MANIFEST_JSON
    man = read_manifest(tmp_path)
    assert man["completed"] == [0, 1] and man["num_completed"] == 2
    assert {k: man[k] for k in info} == info
    assert read_manifest(path) == man
    write_manifest(tmp_path, info, completed=[5, 3])
    assert read_manifest(tmp_path)["completed"] == [3, 5]
    assert sorted(os.listdir(tmp_path)) == [MANIFEST_JSON, "samples"]  # no temporary file left

    with pytest.raises(ValueError, match=r"reserved key\(s\) \['completed'\]"):
        write_manifest(tmp_path, {"completed": []})
    with pytest.raises(FileNotFoundError, match="manifest not found"):
        read_manifest(tmp_path / "samples")
    path.write_text("[1, 2]")
    with pytest.raises(ValueError, match="expected a JSON object"):
        read_manifest(tmp_path)
    path.write_text('{"format": "other"}')
    with pytest.raises(ValueError, match="unsupported format 'other'"):
        read_manifest(tmp_path)


def test_remove_manifest_leftovers_takes_only_dead_writers_manifests(tmp_path, rng):
    _write_many(tmp_path, rng, range(2))
    write_manifest(tmp_path, {"count": 2})
    dead = ".manifest.json.tmp-999999999-0a1b2c3d"  # above any pid_max: a killed writer
    live = f".manifest.json.tmp-{os.getpid()}-0a1b2c3d"  # a writer still running (here: this process)
    others = ["notes.txt", ".notes.json.tmp-999999999-0a1b2c3d", ".manifest.json.old-999999999-0a1b2c3d"]
    for name in (dead, live, *others):
        (tmp_path / name).write_text("{")
    assert [p.name for p in remove_manifest_leftovers(tmp_path)] == [dead]
    assert sorted(os.listdir(tmp_path)) == sorted([live, *others, "manifest.json", "samples"])
    assert sorted(os.listdir(tmp_path / "samples")) == ["000000.exr", "000000.json", "000001.exr", "000001.json"]
    assert remove_manifest_leftovers(tmp_path / "missing") == []
