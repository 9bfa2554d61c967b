"""The data engine's drawn rig: rendered and simulated through it, decoded with the nominal rig, in the sidecar."""

import dataclasses
import json
import math

import numpy as np
import pytest

pytestmark = pytest.mark.mitsuba
pytest.importorskip("mitsuba")

from blender_addon.core import render  # noqa: E402
from blender_addon.core.generate import GenerateConfig, _check_same_scenes, generate  # noqa: E402
from blender_addon.core.spec import MaterialSpec, ObjectSpec, SceneSpec  # noqa: E402
from pbrdf.data import dataset  # noqa: E402
from pbrdf.data import sample as psample  # noqa: E402
from pbrdf.sensor import camera, decode  # noqa: E402
from pbrdf.sensor.rig import DisplaySpec, Rig  # noqa: E402
from pbrdf.sensor.rig_jitter import draw_rig  # noqa: E402

SMALL = {"resolution": 32, "spp": 2, "count": 1, "seed": 5, "noise": False, "keep_stokes": True}
KEYS = ("maps", "mask", "normal", "stokes")


def test_jittered_sample_uses_the_drawn_rig_forward_and_the_nominal_one_to_decode(tmp_path):
    generate(GenerateConfig(out=tmp_path / "off", **SMALL), progress=False)
    generate(GenerateConfig(out=tmp_path / "zero", rig_jitter=0.0, **SMALL), progress=False)
    generate(GenerateConfig(out=tmp_path / "on", rig_jitter=1.0, **SMALL), progress=False)
    off, meta_off = psample.read_sample(tmp_path / "off", 0, keys=KEYS)
    zero, _ = psample.read_sample(tmp_path / "zero", 0, keys=KEYS)
    on, meta = psample.read_sample(tmp_path / "on", 0, keys=KEYS)
    for k in KEYS:  # a zero scale is no jitter, bit for bit
        np.testing.assert_array_equal(zero[k], off[k])
    # Same seed, same draws, recorded; the sidecar's rig and camera model are the decoder's (nominal).
    rig, drawn = draw_rig(Rig(), meta["sample_seed"], 1.0)
    assert meta["rig_jitter"] == json.loads(json.dumps(drawn)) and "rig_jitter" not in meta_off
    as_json = lambda d: json.loads(json.dumps(d))  # noqa: E731 - tuples become lists, as in the sidecar
    assert meta["rig"] == as_json(Rig().to_dict()) and meta["camera_model"] == as_json(Rig().camera.model.to_dict())
    assert meta["spec"]["rig"]["display"]["degree_of_polarization"] == drawn["degree_of_polarization"] < 1
    # The scene is the same (its geometry), the render sees the drawn display, the maps the drawn camera.
    np.testing.assert_array_equal(on["normal"], off["normal"])
    assert not np.array_equal(on["stokes"], off["stokes"])
    up = np.repeat(np.repeat(on["stokes"], 2, axis=0), 2, axis=1)
    raws = camera.simulate_capture(up, rig.camera.model, noise=False)
    expected = decode.decode(raws, Rig().camera.model, grid="half")
    m = on["mask"]
    np.testing.assert_allclose(on["maps"][m], expected.maps[m], rtol=1e-5, atol=1e-6)
    own = decode.decode(raws, rig.camera.model, grid="half")
    assert np.abs(own.maps[m] - on["maps"][m]).max() > 1e-3  # decoding with the drawn rig would differ


def test_old_manifests_without_the_new_fields_still_resume(tmp_path):
    """A split rendered before rig_jitter and the corpus existed (train-light, running now) keeps resuming."""
    cfg = GenerateConfig(out=tmp_path, **SMALL)
    generate(cfg, progress=False)
    doc = json.loads((tmp_path / "manifest.json").read_text())
    for k in ("rig_jitter", "corpus", "corpus_fraction", "corpus_digest"):
        del doc["config"][k]
    (tmp_path / "manifest.json").write_text(json.dumps(doc))
    info = {"config": json.loads(json.dumps(dataclasses.asdict(cfg), default=str)) | {"corpus_digest": None}}
    _check_same_scenes(tmp_path, info)  # no error
    with pytest.raises(ValueError, match=r"rig_jitter=0.0 there, 1.0 now"):
        generate(dataclasses.replace(cfg, resume=True, rig_jitter=1.0), progress=False)
    assert dataset.read_manifest(tmp_path)["completed"] == [0]


def _mirror_sphere_dop(dop: float) -> float:
    """Median DoP of the light a smooth gold sphere reflects near normal incidence, under a display of DoP ``dop``."""
    m = np.eye(4)
    m[:3, :3] *= 0.2
    m[:3, 3] = (0.0, 0.0, -0.6)
    gold = MaterialSpec.metal("gold", eta=(0.18, 0.5, 1.3), k=(3.2, 2.3, 1.85), roughness=0.05)
    rig = Rig(display=DisplaySpec(degree_of_polarization=dop, pattern="white"))
    spec = SceneSpec(rig=rig, objects=(ObjectSpec("s", "builtin:sphere", tuple(map(tuple, m)), "gold"),),
                     materials=(gold,), seed=0)  # fmt: skip
    res = render.render_stokes(spec, render.RenderSettings(resolution=32, spp=16))
    assert res.display == "emitter"
    s = res.stokes[..., 1, :]  # green channel (H, W, 4)
    lit = s[..., 0] > 0.5 * s[..., 0].max()
    return float(np.median(np.linalg.norm(s[..., 1:], axis=-1)[lit] / s[..., 0][lit]))


def test_display_degree_of_polarization_is_rendered():
    """Metal reflection near normal incidence keeps the light's degree of polarization (Fresnel: no diattenuation)."""
    full, half = _mirror_sphere_dop(1.0), _mirror_sphere_dop(0.5)
    assert full > 0.9 and math.isclose(half, 0.5 * full, rel_tol=0.1), (full, half)
