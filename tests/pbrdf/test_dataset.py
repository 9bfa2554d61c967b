"""Dataset samples on disk: exact round trips, validation, completeness, shards and resume."""

import json
import logging
import os

import numpy as np
import pytest

from pbrdf.data.dataset import (
    CHANNELS,
    MANIFEST_JSON,
    REQUIRED_KEYS,
    SAMPLE_FORMAT,
    cleanup_partial,
    completed_indices,
    parse_shard,
    plan_work,
    read_manifest,
    read_sample,
    sample_paths,
    shard_indices,
    validate_sample,
    write_manifest,
    write_sample,
)
from pbrdf.io.exr import MissingChannelError, exr_channel_names, read_exr, read_exr_header
from pbrdf.sensor.camera import CameraModel
from pbrdf.sensor.decode import NINE_MAP_NAMES

H, W = 4, 6


def make_sample(rng, *, stokes=False, raw=False):
    """A valid sample on an (H, W) grid and its metadata."""
    mask = rng.random((H, W)) > 0.3
    mask[0, 0], mask[0, 1] = True, False
    n = rng.normal(size=(H, W, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    sample = {
        "maps": rng.normal(size=(H, W, 9)).astype(np.float32),
        "mask": mask,
        "normal": np.where(mask[..., None], n, 0).astype(np.float32),
        "albedo": rng.uniform(0, 1, (H, W, 3)).astype(np.float32),
        "roughness": rng.uniform(0, 1, (H, W)).astype(np.float32),
        "metallic": rng.uniform(0, 1, (H, W)).astype(np.float32),
        "depth": np.where(mask, rng.uniform(0.3, 2.0, (H, W)), 0).astype(np.float32),
    }
    sample["albedo"][0, 0] = [0.0, 1.0, 0.5]  # range ends are valid
    metadata = {
        "rig": {"display_distance_m": 0.4, "pose": np.eye(4)},  # numpy values become JSON lists
        "materials": [{"id": "gold", "disney": {"metallic": 1.0, "roughness": np.float64(0.25)}}],
        "seed": 1234,
        "versions": {"pbrdf": "0.1.0"},
    }
    if stokes:
        sample["stokes"] = rng.normal(size=(H, W, 3, 4)).astype(np.float32)
    if raw:
        model = CameraModel(exposures=(0.01, 0.04))
        base = rng.integers(16, 900, (2 * H, 2 * W))
        sample["raw"] = np.stack([base, np.minimum(4 * base, 4095)]).astype(np.uint16)
        metadata["camera_model"] = model.to_dict()
    return sample, metadata


def assert_samples_equal(got, want):
    assert sorted(got) == sorted(want)
    for key, arr in want.items():
        assert got[key].dtype == arr.dtype, key
        assert got[key].shape == arr.shape, key
        np.testing.assert_array_equal(got[key], arr, err_msg=key)
        if arr.dtype == np.float32:  # bit for bit (the test data has no -0.0, but say so anyway)
            np.testing.assert_array_equal(got[key].view(np.uint32), arr.view(np.uint32), err_msg=key)


def test_channel_names_are_pinned():
    assert CHANNELS["maps"] == tuple(f"maps.{n}" for n in NINE_MAP_NAMES)
    assert CHANNELS["maps"][0] == "maps.R_unpol" and CHANNELS["maps"][8] == "maps.B_CP"
    assert CHANNELS["mask"] == ("mask.Y",)
    assert CHANNELS["normal"] == ("normal.X", "normal.Y", "normal.Z")
    assert CHANNELS["albedo"] == ("albedo.R", "albedo.G", "albedo.B")
    assert (CHANNELS["roughness"], CHANNELS["metallic"], CHANNELS["depth"]) == (
        ("roughness.Y",),
        ("metallic.Y",),
        ("depth.Z",),
    )
    assert CHANNELS["stokes"][:5] == ("stokes.R.S0", "stokes.R.S1", "stokes.R.S2", "stokes.R.S3", "stokes.G.S0")
    assert len(CHANNELS["stokes"]) == 12
    assert sum(len(v) for v in CHANNELS.values()) == 31


@pytest.mark.parametrize(("stokes", "raw"), [(False, False), (True, True)])
def test_round_trip_exact(tmp_path, rng, stokes, raw):
    sample, metadata = make_sample(rng, stokes=stokes, raw=raw)
    sidecar = write_sample(tmp_path, 12, sample, metadata)
    paths = sample_paths(tmp_path, 12)
    assert sidecar == paths.sidecar == tmp_path / "samples" / "000012.json"
    assert paths.exr.name == "000012.exr"
    assert paths.raw.is_dir() == raw

    keys = [k for k in ("maps", "mask", "normal", "albedo", "roughness", "metallic", "depth", "stokes") if k in sample]
    expected_channels = [c for k in keys for c in CHANNELS[k]]
    assert sorted(exr_channel_names(paths.exr)) == sorted(expected_channels)
    assert read_exr_header(paths.exr)["attributes"] == {"pdir.format": SAMPLE_FORMAT, "pdir.index": "12"}

    got, meta = read_sample(tmp_path, 12)
    assert_samples_equal(got, sample)
    assert got["mask"].dtype == np.bool_
    assert meta["index"] == 12 and meta["channels"] == expected_channels and meta["shape"] == [H, W]
    assert meta["rig"]["pose"] == np.eye(4).tolist()
    assert meta["materials"][0]["disney"]["roughness"] == 0.25
    caller = {k: v for k, v in meta.items() if k in metadata}
    assert json.loads(json.dumps(metadata, default=lambda v: v.tolist() if hasattr(v, "tolist") else v)) == caller
    if raw:
        assert meta["raw_capture"] == "000012_raw"
        assert CameraModel.from_dict(meta["camera_model"]) == CameraModel(exposures=(0.01, 0.04))

    # the same through the EXR or sidecar path, with verification
    for p in (paths.exr, paths.sidecar):
        again, _ = read_sample(p, verify=True)
        assert_samples_equal(again, sample)
    assert sorted(os.listdir(tmp_path / "samples")) == sorted(
        ["000012.exr", "000012.json"] + (["000012_raw"] if raw else [])
    )


def test_channels_hold_what_their_names_say(tmp_path, rng):
    """Not only a round trip: each EXR channel holds the named component."""
    sample, metadata = make_sample(rng, stokes=True)
    write_sample(tmp_path, 0, sample, metadata)
    ch = read_exr(sample_paths(tmp_path, 0).exr)
    np.testing.assert_array_equal(ch["maps.G_LP"], sample["maps"][..., NINE_MAP_NAMES.index("G_LP")])
    np.testing.assert_array_equal(ch["maps.G_LP"], sample["maps"][..., 4])
    np.testing.assert_array_equal(ch["normal.Y"], sample["normal"][..., 1])
    np.testing.assert_array_equal(ch["albedo.B"], sample["albedo"][..., 2])
    np.testing.assert_array_equal(ch["stokes.G.S2"], sample["stokes"][..., 1, 2])
    np.testing.assert_array_equal(ch["stokes.B.S0"], sample["stokes"][..., 2, 0])
    np.testing.assert_array_equal(ch["mask.Y"], sample["mask"].astype(np.uint32))
    np.testing.assert_array_equal(ch["depth.Z"], sample["depth"])


def test_read_only_requested_keys(tmp_path, rng):
    sample, metadata = make_sample(rng, stokes=True, raw=True)
    write_sample(tmp_path, 0, sample, metadata)
    got, _ = read_sample(tmp_path, 0, keys=["normal", "mask"])
    assert list(got) == ["normal", "mask"]
    np.testing.assert_array_equal(got["normal"], sample["normal"])
    got, _ = read_sample(tmp_path, 0, keys=["raw"])
    assert list(got) == ["raw"]
    np.testing.assert_array_equal(got["raw"], sample["raw"])
    with pytest.raises(ValueError, match=r"unknown sample key\(s\) \['normals'\]"):
        read_sample(tmp_path, 0, keys=["normals"])

    plain, metadata = make_sample(rng)
    write_sample(tmp_path, 1, plain, metadata)
    with pytest.raises(MissingChannelError, match=r"sample has no \['stokes'\]"):
        read_sample(tmp_path, 1, keys=["stokes"])
    assert "stokes" not in read_sample(tmp_path, 1)[0]


def _nan_maps(s, m):
    s["maps"][1, 2, 3] = np.nan


def _short_normal(s, m):
    s["normal"][0, 0] *= 0.99


def _bright_albedo(s, m):
    s["albedo"][1, 1, 0] = 1.01


def _no_depth(s, m):
    del s["depth"]


def _small_albedo(s, m):
    s["albedo"] = s["albedo"][:, :-1]


def _float_mask(s, m):
    s["mask"] = s["mask"].astype(np.float32)


def _double_maps(s, m):
    s["maps"] = s["maps"].astype(np.float64)


def _normal_outside(s, m):
    s["normal"][0, 1] = [0, 0, 1]


def _depth_inside(s, m):
    s["depth"][0, 0] = 0


def _typo_key(s, m):
    s["normals"] = s["normal"]


def _inf_stokes(s, m):
    s["stokes"] = np.zeros((H, W, 3, 4), np.float32)
    s["stokes"][0, 0, 0, 0] = np.inf


def _negative_roughness(s, m):
    s["roughness"][2, 2] = -0.1


def _list_metallic(s, m):
    s["metallic"] = s["metallic"].tolist()


def _raw_without_model(s, m):
    s["raw"] = np.zeros((2, 2 * H, 2 * W), np.uint16)


def _raw_wrong_size(s, m):
    s["raw"] = np.zeros((2, H, W), np.uint16)
    m["camera_model"] = CameraModel(exposures=(0.01, 0.04)).to_dict()


def _raw_too_few_frames(s, m):
    s["raw"] = np.zeros((1, 2 * H, 2 * W), np.uint16)
    m["camera_model"] = CameraModel(exposures=(0.01, 0.04)).to_dict()


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (_nan_maps, r"sample\['maps'\] contains NaN \(1 values, first at \(row 1, col 2\)\)"),
        (_short_normal, r"sample\['normal'\] must be unit vectors inside the mask"),
        (_bright_albedo, r"sample\['albedo'\] values must be in \[0, 1\]; got \[0, 1.01\]"),
        (_no_depth, r"missing required key\(s\) \['depth'\]"),
        (_small_albedo, r"sample\['albedo'\] has shape \(4, 5, 3\); \(H, W\) must be \(4, 6\)"),
        (_float_mask, r"sample\['mask'\] must have dtype bool; got float32"),
        (_double_maps, r"sample\['maps'\] must have dtype float32; got float64"),
        (_normal_outside, r"sample\['normal'\] must be 0 outside the mask"),
        (_depth_inside, r"sample\['depth'\] must be > 0 inside the mask"),
        (_typo_key, r"unknown key\(s\) \['normals'\]"),
        (_inf_stokes, r"sample\['stokes'\] contains Inf"),
        (_negative_roughness, r"sample\['roughness'\] values must be in \[0, 1\]"),
        (_list_metallic, r"sample\['metallic'\] must be a numpy array; got list"),
        (_raw_without_model, r"needs metadata\['camera_model'\]"),
        (_raw_wrong_size, r"sample\['raw'\] must have shape \(E, 2H, 2W\) = \(E, 8, 12\)"),
        (_raw_too_few_frames, r"1 frames for 2 exposures"),
    ],
)
def test_validation_errors(tmp_path, rng, mutate, match):
    sample, metadata = make_sample(rng)
    mutate(sample, metadata)
    with pytest.raises(ValueError, match=match):
        validate_sample(sample, metadata)
    with pytest.raises(ValueError, match=match):
        write_sample(tmp_path, 0, sample, metadata)
    assert not (tmp_path / "samples").exists()  # nothing written


def test_metadata_errors(tmp_path, rng):
    sample, _ = make_sample(rng)
    with pytest.raises(ValueError, match=r"reserved key\(s\) \['sha256'\]"):
        write_sample(tmp_path, 0, sample, {"sha256": "x"})
    with pytest.raises(ValueError, match="metadata is not valid JSON"):
        write_sample(tmp_path, 0, sample, {"bad": float("nan")})
    with pytest.raises(ValueError, match="metadata is not valid JSON"):
        write_sample(tmp_path, 0, sample, {"bad": object()})
    with pytest.raises(ValueError, match="index must be an integer >= 0"):
        write_sample(tmp_path, -1, sample, {})
    assert not (tmp_path / "samples").exists()


def test_rewrite_replaces_a_sample(tmp_path, rng):
    first, meta1 = make_sample(rng, raw=True)
    write_sample(tmp_path, 3, first, meta1)
    second, meta2 = make_sample(rng)
    write_sample(tmp_path, 3, second, {**meta2, "seed": 99})
    got, meta = read_sample(tmp_path, 3, verify=True)
    assert_samples_equal(got, second)
    assert meta["seed"] == 99 and "raw_capture" not in meta
    assert not sample_paths(tmp_path, 3).raw.exists()  # the old raw folder is gone


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


def test_sidecar_is_written_last(tmp_path, rng, monkeypatch):
    """A crash after the EXR (and raw) but before the sidecar leaves an incomplete sample."""
    import pbrdf.data.dataset as ds

    def crash(path, text):
        raise KeyboardInterrupt

    write_sample(tmp_path, 0, *make_sample(rng))  # a complete sample, then a rewrite that crashes
    monkeypatch.setattr(ds, "atomic_write_text", crash)
    with pytest.raises(KeyboardInterrupt):
        write_sample(tmp_path, 0, *make_sample(rng, raw=True))
    monkeypatch.undo()
    paths = sample_paths(tmp_path, 0)
    # the old sidecar went first: it cannot vouch for the new EXR (even without hashing)
    assert paths.exr.is_file() and paths.raw.is_dir() and not paths.sidecar.exists()
    assert completed_indices(tmp_path) == set()
    assert plan_work(tmp_path, 1, resume=True) == [0]
    assert sorted(p.name for p in cleanup_partial(tmp_path)) == ["000000.exr", "000000_raw"]
    assert os.listdir(tmp_path / "samples") == []


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


def test_required_keys_documented():
    assert REQUIRED_KEYS == ("maps", "mask", "normal", "albedo", "roughness", "metallic", "depth")
