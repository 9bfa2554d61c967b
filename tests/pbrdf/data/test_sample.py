"""One dataset sample on disk: exact round trips, channel names, validation, write order."""

import json
import os

import numpy as np
import pytest

from pbrdf.data import sample as sample_module
from pbrdf.data.dataset import cleanup_partial, completed_indices, plan_work
from pbrdf.data.sample import (
    CHANNELS,
    REQUIRED_KEYS,
    SAMPLE_FORMAT,
    check_complete,
    read_sample,
    sample_paths,
    validate_sample,
    write_sample,
)
from pbrdf.io.exr import MissingChannelError, exr_channel_names, read_exr, read_exr_header
from pbrdf.sensor.camera import CameraModel
from pbrdf.sensor.decode import NINE_MAP_NAMES
from tests.helpers import H, W, assert_samples_equal, make_sample


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
    assert CHANNELS["object"] == ("object.Y",)
    assert sum(len(v) for v in CHANNELS.values()) == 32


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
    assert meta["rig"]["camera"]["to_world"] == np.eye(4).tolist()
    assert meta["materials"][0]["disney"]["roughness"] == 0.25
    caller = {k: v for k, v in meta.items() if k in metadata}
    assert json.loads(json.dumps(metadata, default=lambda v: v.tolist() if hasattr(v, "tolist") else v)) == caller
    if raw:
        assert meta["raw_capture"] == "000012_raw"
        assert CameraModel.from_dict(meta["camera_model"]) == CameraModel(exposures=(0.01, 0.04))
        # The raw folder is a capture a user could have taken: calibrated, with the sample's rig.
        capture_json = json.loads((paths.raw / "capture.json").read_text())
        assert capture_json["radiometry"] == "calibrated" and capture_json["rig"] == meta["rig"]

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


def test_sidecar_is_written_last(tmp_path, rng, monkeypatch):
    """A crash after the EXR (and raw) but before the sidecar leaves an incomplete sample."""

    def crash(path, text):
        raise KeyboardInterrupt

    write_sample(tmp_path, 0, *make_sample(rng))  # a complete sample, then a rewrite that crashes
    monkeypatch.setattr(sample_module, "atomic_write_text", crash)
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


def test_check_complete_says_what_is_missing(tmp_path, rng):
    write_sample(tmp_path, 0, *make_sample(rng))
    assert check_complete(tmp_path, 0)["index"] == 0
    paths = sample_paths(tmp_path, 0)
    paths.exr.write_bytes(paths.exr.read_bytes()[:-1])
    with pytest.raises(ValueError, match="bytes; sidecar says"):
        check_complete(tmp_path, 0)
    paths.exr.unlink()
    with pytest.raises(FileNotFoundError, match="EXR of sidecar"):
        check_complete(tmp_path, 0)
    with pytest.raises(FileNotFoundError, match="sidecar not found"):
        check_complete(tmp_path, 1)


def test_required_keys_documented():
    assert REQUIRED_KEYS == ("maps", "mask", "normal", "albedo", "roughness", "metallic", "depth")


def test_object_channel_defines_the_ground_truth_region(tmp_path, rng):
    sample, metadata = make_sample(rng)
    obj = np.where(sample["mask"], 0.0, -1.0).astype(np.float32)
    obj[0, 1] = 0.0  # an object pixel the decoder did not measure: outside the mask, inside the truth
    sample["object"] = obj
    with pytest.raises(ValueError, match=r"must be unit vectors on the objects"):
        validate_sample(sample)  # its normal is still 0
    sample["normal"][0, 1] = [0.0, 0.0, 1.0]
    sample["depth"][0, 1] = 1.0
    validate_sample(sample)
    write_sample(tmp_path, 0, sample, metadata)
    back, _ = read_sample(tmp_path, 0)
    np.testing.assert_array_equal(back["object"], obj)
    stray = dict(sample, object=np.full_like(obj, -1.0))
    with pytest.raises(ValueError, match=r"mask'\] must lie on the objects"):
        validate_sample(stray)
    with pytest.raises(ValueError, match="object indices"):
        validate_sample(dict(sample, object=obj + 0.5))
