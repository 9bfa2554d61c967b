"""Packs (network.packed, headless/pack.py): same items as the EXR dataset, resumable writing, hash checks, workers."""

import numpy as np
import pytest
import torch

from network import packed
from network.data import SampleDataset
from network.packed import PackedDataset, pack_split
from network.schedules import StepBatches
from pbrdf.data import sample as psample
from pbrdf.data.splits import require_role
from tests.helpers import make_sample
from tests.network.test_data import _forge

#: float16 storage: each value within 2**-11 relative (normal range) or 2**-25 absolute (subnormals),
#: times the calibrated gain 3.5 for the maps; the exposure-invariant scale moves by as much.
RTOL, ATOL = 2e-3, 1e-6


def _write_split(root, count, rng, *, hw=(12, 10), split=None, first=0):
    """Samples ``first, ..., first + count - 1`` of ``hw`` pixels (unit normals, depth inside the mask, intrinsics)."""
    for i in range(first, first + count):
        sample, meta = make_sample(rng)
        h, w = hw
        mask = rng.random((h, w)) > 0.3
        mask[0, 0] = True
        n = rng.normal(size=(h, w, 3))
        n[..., 2] = np.abs(n[..., 2]) + 0.1
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        sample = {
            "maps": (rng.lognormal(-3, 2, (h, w, 9)) * np.r_[np.ones(6), rng.uniform(-1, 1, 3)]).astype(np.float32),
            "mask": mask,
            "normal": np.where(mask[..., None], n, 0).astype(np.float32),
            "albedo": rng.uniform(0, 1, (h, w, 3)).astype(np.float32),
            "roughness": rng.uniform(0, 1, (h, w)).astype(np.float32),
            "metallic": rng.uniform(0, 1, (h, w)).astype(np.float32),
            "depth": np.where(mask, rng.uniform(0.4, 1.2, (h, w)), 0).astype(np.float32),
        }
        meta = {**meta, "rig": {"display": {"radiance": 0.5 + i}}, "intrinsics": [[20.0, 0, w / 2], [0, 20.0, h / 2],
                                                                                  [0, 0, 1]]}  # fmt: skip
        if split is not None:
            meta["split"] = split
        psample.write_sample(root, i, sample, meta)
    return root


@pytest.fixture
def split(tmp_path):
    return _write_split(tmp_path / "split", 5, np.random.default_rng(3))


def _assert_items_match(got, want, rtol=RTOL, atol=ATOL):
    assert list(got) == list(want)
    for key in want:
        assert got[key].shape == want[key].shape and got[key].dtype == want[key].dtype, key
        torch.testing.assert_close(got[key], want[key], rtol=rtol, atol=atol, msg=key)


@pytest.mark.parametrize("input_scale", ["calibrated", "exposure-invariant"])
@pytest.mark.parametrize("size", [None, 16])
def test_pack_yields_what_the_exr_dataset_yields(split, tmp_path, input_scale, size):
    kw = {"input_scale": input_scale, "light_input": True, "size": size}
    pack_split(split, tmp_path / "p16", shard_samples=2, size=size)
    pack_split(split, tmp_path / "p32", shard_samples=3, dtype="float32")
    exr = SampleDataset(split, **kw)
    half, full = PackedDataset(tmp_path / "p16", **kw), PackedDataset(tmp_path / "p32", **kw)
    assert half.indices == full.indices == exr.indices == [0, 1, 2, 3, 4]
    for i in range(len(exr)):
        want = exr[i]
        _assert_items_match(half[i], want)
        _assert_items_match(full[i], want, rtol=0, atol=0)  # float32 is exact, resized on load like the EXR
    assert not torch.equal(half[0]["maps"], exr[0]["maps"])  # float16 rounds (the tolerance is not vacuous)
    sub = PackedDataset(tmp_path / "p16", indices=[4, 1, 9])
    assert sub.indices == [4, 1] and len(sub) == 2


def test_pack_is_resumable_after_a_kill(split, tmp_path, monkeypatch):
    clean = pack_split(split, tmp_path / "clean", shard_samples=2)
    real, calls = packed._read_source, []

    def dies_on_the_fourth(*args):
        calls.append(args[1])
        if len(calls) == 4:  # inside the second shard, after the first was listed
            raise KeyboardInterrupt
        return real(*args)

    monkeypatch.setattr(packed, "_read_source", dies_on_the_fourth)
    with pytest.raises(KeyboardInterrupt):
        pack_split(split, tmp_path / "p", shard_samples=2)
    monkeypatch.setattr(packed, "_read_source", real)
    index = packed.read_index(tmp_path / "p")
    assert [s["samples"] for s in index["shards"]] == [[0, 1]]
    (tmp_path / "p" / ".shard-00001.bin.tmp-999999999-0a1b2c3d").write_bytes(b"killed writer")
    with pytest.raises(FileExistsError, match="resume=True"):
        pack_split(split, tmp_path / "p", shard_samples=2)
    with pytest.raises(ValueError, match="dtype='float16', not 'float32'"):
        pack_split(split, tmp_path / "p", shard_samples=2, dtype="float32", resume=True)
    report = pack_split(split, tmp_path / "p", shard_samples=2, resume=True)
    assert report == {**clean, "shards_written": 2, "samples_written": 3}
    ref, got = packed.read_index(tmp_path / "clean"), packed.read_index(tmp_path / "p")
    assert [(s["file"], s["samples"], s["sha256"]) for s in got["shards"]] == [
        (s["file"], s["samples"], s["sha256"]) for s in ref["shards"]
    ]
    assert sorted(p.name for p in (tmp_path / "p").iterdir()) == sorted(p.name for p in (tmp_path / "clean").iterdir())
    # Samples rendered later join in a new shard; nothing is packed twice.
    _write_split(tmp_path / "more", 7, np.random.default_rng(3))
    assert pack_split(tmp_path / "more", tmp_path / "p", shard_samples=2, resume=True)["samples_written"] == 2
    held = [i for s in packed.read_index(tmp_path / "p")["shards"] for i in s["samples"]]
    assert sorted(held) == list(range(7)) and len(held) == 7


def test_corrupt_shard_is_refused_with_one_line(split, tmp_path):
    pack_split(split, tmp_path / "p", shard_samples=2)
    shard = tmp_path / "p" / "shard-00001.bin"
    data = bytearray(shard.read_bytes())
    data[100] ^= 1
    shard.write_bytes(bytes(data))
    with pytest.raises(ValueError, match=r"shard-00001\.bin: shard is corrupt \(sha256") as err:
        PackedDataset(tmp_path / "p")
    assert "\n" not in str(err.value)
    PackedDataset(tmp_path / "p", verify=False)  # opening without the check is possible
    with pytest.warns(UserWarning, match="shard-00001.bin: shard is corrupt"):  # a resume packs its samples again
        pack_split(split, tmp_path / "p", shard_samples=2, resume=True)
    assert [s["file"] for s in packed.read_index(tmp_path / "p")["shards"]] == [
        "shard-00000.bin", "shard-00002.bin", "shard-00003.bin"
    ]  # fmt: skip
    assert not shard.exists() and len(PackedDataset(tmp_path / "p")) == 5
    (tmp_path / "p" / "shard-00000.bin").unlink()
    with pytest.raises(ValueError, match="shard-00000.bin: shard listed in index.json is missing"):
        PackedDataset(tmp_path / "p")


def test_pack_refuses_bad_samples_and_mixed_sizes(tmp_path):
    rng = np.random.default_rng(4)
    _write_split(tmp_path / "mixed", 1, rng)
    _write_split(tmp_path / "mixed", 1, rng, hw=(8, 8), first=1)
    with pytest.raises(ValueError, match=r"000001\.exr: maps are 8 x 8, the pack's are 12 x 10"):
        pack_split(tmp_path / "mixed", tmp_path / "p")
    assert pack_split(tmp_path / "mixed", tmp_path / "q", size=8)["samples"] == 2
    bad = _write_split(tmp_path / "bad", 1, rng)
    _forge(bad, 0, "albedo", lambda a: np.where(np.arange(a.shape[1])[:, None] == 3, 1.5, a))  # hash re-signed
    with pytest.raises(ValueError, match=r"000000\.exr: albedo values must be in \[0, 1\]"):
        pack_split(bad, tmp_path / "r")
    with pytest.raises(ValueError, match="shard_samples must be a positive integer"):
        pack_split(bad, tmp_path / "r", shard_samples=0)


def test_packed_test_split_keeps_its_role(tmp_path):
    src = _write_split(tmp_path / "t", 1, np.random.default_rng(6), split="test-procedural")
    pack_split(src, tmp_path / "p")
    with pytest.raises(ValueError, match="test split 'test-procedural'; training may read only train"):
        require_role(tmp_path / "p", ("train",), "training")


def test_batches_do_not_depend_on_the_worker_count(split, tmp_path):
    from network.train import _loader

    pack_split(split, tmp_path / "p", shard_samples=2)
    ds = PackedDataset(tmp_path / "p", size=16, input_scale="calibrated")
    runs = []
    for workers in (0, 2):
        sampler = StepBatches(len(ds), 0, "synthetic", list(range(6)), 2, 0, 1)
        runs.append(list(_loader(ds, sampler, workers)))
    assert len(runs[0]) == len(runs[1]) == 6
    for a, b in zip(*runs, strict=True):
        assert list(a) == list(b)
        for key in a:
            assert torch.equal(a[key], b[key]), key


def test_training_on_a_float32_pack_equals_training_on_the_split(split, tmp_path):
    from network.train import TrainConfig, train

    pack_split(split, tmp_path / "p", dtype="float32")
    kw = {"config": "toy", "steps": 2, "batch_size": 2, "seed": 0, "tensorboard": False, "device": "cpu"}
    on_split = train(TrainConfig(data=split, out=tmp_path / "a", **kw), progress=False)
    on_pack = train(TrainConfig(data=tmp_path / "p", out=tmp_path / "b", workers=2, **kw), progress=False)
    assert len(on_pack) == 2 and on_pack == on_split


def test_pack_cli(split, tmp_path, capsys):
    from headless import pack

    assert pack.main(["--input", str(split), "--out", str(tmp_path / "p"), "--shard-samples", "4", "--quiet"]) == 0
    assert "5 samples in 2 shards" in capsys.readouterr().out
    assert pack.main(["--input", str(split), "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pass --resume to continue" in err[0]
    assert pack.main(["--input", str(tmp_path / "none"), "--out", str(tmp_path / "q")]) == 2
    assert "dataset folder not found" in capsys.readouterr().err
