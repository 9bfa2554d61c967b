"""network/robustness.py and robustness_report.py: levels, the display basis, the cell captures, tables.

The sweep on rendered scenes (nominal cell = plain evaluation, true rig closer than nominal,
resume) is tested in tests/headless/test_robustness.py.
"""

import math

import numpy as np
import pytest

from network import robustness as rb
from network import robustness_report as rr
from pbrdf.data import capture as pcapture
from pbrdf.sensor.camera import CameraModel, simulate_capture
from pbrdf.sensor.decode import decode


def emitted(theta: float, dop: float = 1.0) -> np.ndarray:
    """Stokes vector of the display's light: linear at ``theta`` (rig convention), degree ``dop``."""
    return np.array([1.0, dop * math.cos(2 * theta), dop * math.sin(2 * theta), 0.0])


def test_display_stokes_is_a_linear_scene_under_another_display(rng):
    # An independent scene: a random Mueller matrix per pixel and colour acting on the emitted light.
    m = rng.normal(size=(4, 4, 3, 4, 4))
    basis = {k: m @ emitted(math.radians(deg)) for k, deg in (("v", 90), ("h", 0), ("d", 45))}
    for dop, err in ((0.9, 0.0), (1.0, 5.0), (0.95, -3.0), (0.0, 0.0)):
        want = m @ emitted(math.pi / 2 + math.radians(err), dop)
        np.testing.assert_allclose(rb.display_stokes(basis, dop, err), want, atol=1e-12)
    assert rb.display_stokes(basis) is basis["v"]  # nominal: the rendered images themselves
    with pytest.raises(ValueError, match="dop"):
        rb.display_stokes(basis, 1.2)


def test_levels_make_the_camera_of_the_perturbed_rig():
    nominal = CameraModel()
    shape = (64, 48)
    cam = rb.true_camera("crosstalk", 0.1, nominal, display_radiance=2.0, raw_shape=shape)
    assert np.allclose(cam.crosstalk, [[1, 0.1, 0.05], [0.1, 1, 0.1], [0.05, 0.1, 1]])
    assert rb.true_camera("ambient", 0.05, nominal, display_radiance=2.0, raw_shape=shape).ambient == (0.1,) * 3
    cam = rb.true_camera("qwp_retardance", 10.0, nominal, display_radiance=1.0, raw_shape=shape)
    assert cam.qwp_retardance == pytest.approx((math.radians(100),) * 3)
    assert rb.true_camera("qwp_angle", 5.0, nominal, display_radiance=1.0, raw_shape=shape).qwp_angle == pytest.approx(
        math.radians(5)
    )
    assert (
        rb.true_camera("extinction", 20.0, nominal, display_radiance=1.0, raw_shape=shape).extinction_ratio
        == (20.0,) * 3
    )
    for term in ("display_dop", "display_angle"):  # the scene's light: the camera is the nominal one
        assert rb.true_camera(term, 0.9, nominal, display_radiance=1.0, raw_shape=shape) is nominal
    assert rb.true_camera("crosstalk", 0.0, nominal, display_radiance=1.0, raw_shape=shape) is nominal
    with pytest.raises(ValueError, match="term"):
        rb.true_camera("gamma", 1.0, nominal, display_radiance=1.0, raw_shape=shape)


def test_vignetting_level_is_the_light_lost_at_the_corner():
    shape = (40, 64)
    f = rb.vignetting_focal_for(0.3, shape)
    d2 = (20 - 0.5) ** 2 + (32 - 0.5) ** 2  # the corner pixel centre's squared distance from the frame centre
    assert math.cos(math.atan(math.sqrt(d2) / f)) ** 4 == pytest.approx(0.7)
    assert rb.vignetting_focal_for(0.0, shape) == math.inf
    with pytest.raises(ValueError, match="loss"):
        rb.vignetting_focal_for(1.0, shape)


def test_plan_has_one_nominal_cell_and_no_true_decoder_for_display_terms():
    plan = rb.cell_plan()
    keys = [rb.cell_key(*c) for c in plan]
    assert keys[0] == "nominal" and len(set(keys)) == len(keys)
    invertible = sum(t.invertible for t in rb.TERMS)
    assert len(plan) == 1 + sum(len(t.levels) - 1 for t in rb.TERMS) + 4 * invertible
    assert not any(k.startswith("display") and k.endswith("true") for k in keys)
    with pytest.raises(ValueError, match="no decoder inverts"):
        rb.run_cell(None, {}, ".", [0], {}, None, "display_dop", 1, "true")


def _capture(rng, model: CameraModel, shape=(16, 16)):
    """A capture of a smooth scene and its basis (render grid ``shape``): the sample's own, in memory."""
    v = np.zeros((*shape, 3, 4))
    v[..., 0] = 0.05 + 0.05 * rng.random((*shape, 1))
    v[..., 1] = -0.5 * v[..., 0]
    basis = {"v": v, "h": v * [1, -1, 1, 1], "d": v * [1, 0, 1, 1]}
    up = np.repeat(np.repeat(v, 2, axis=0), 2, axis=1)
    raws = simulate_capture(up, model, rng=np.random.default_rng([7, 1]))
    return basis, pcapture.Capture(raws=raws, model=model, metadata={"note": "kept"})


def test_nominal_capture_is_the_samples_own_and_the_true_one_carries_the_belief(rng, tmp_path):
    model = CameraModel()
    basis, cap = _capture(rng, model)
    folder = rb.capture_scene(tmp_path / "nominal", basis, cap, 7, "nominal", 0.0, "nominal")
    again = pcapture.load_capture(folder)
    assert np.array_equal(again.raws, cap.raws) and again.dark is None and again.metadata["note"] == "kept"
    folder = rb.capture_scene(tmp_path / "amb-nominal", basis, cap, 7, "ambient", 0.05, "nominal")
    assert pcapture.load_capture(folder).dark is None and pcapture.load_capture(folder).model == model
    folder = rb.capture_scene(tmp_path / "amb-true", basis, cap, 7, "ambient", 0.05, "true")
    true = pcapture.load_capture(folder)
    assert true.dark is not None and true.model.ambient == (0.05,) * 3
    # The dark frame removes the room light: unpol (s0 + s1) back near the truth, 0.05 too high without it.
    want = (basis["v"][..., 0] + basis["v"][..., 1]).mean()
    with_dark = decode(true.raws, true.model, dark=true.dark).maps[..., :3].mean()
    without = decode(true.raws, model).maps[..., :3].mean()
    assert abs(with_dark - want) < 0.005 and without - want == pytest.approx(0.05, abs=0.005)


def _cell(term, index, decoder, normal, psnr, scenes=(0, 1)):
    rows = [{"index": i, "pixels": 100, "mask_iou": 0.9,
             "ours": {"normal_mae": n, "albedo_psnr": p, "roughness_rmse": 0.1, "metallic_rmse": 0.05}}
            for i, n, p in zip(scenes, normal, psnr, strict=True)]  # fmt: skip
    level = 0.0 if term == "nominal" else next(t for t in rb.TERMS if t.name == term).levels[index]
    return {"term": term, "level_index": index, "level": level, "decoder": decoder, "scenes": list(scenes),
            "rows": rows, "summary": rb._summary(rows), "seconds": 1.0}  # fmt: skip


def test_report_pairs_each_level_with_the_nominal_cell():
    cells = {"nominal": _cell("nominal", 0, "nominal", [5.0, 7.0], [20.0, 22.0])}
    for i in range(1, 5):  # with the nominal decoder the normal error grows 0.5 deg and PSNR falls 2 dB per level
        cells[rb.cell_key("crosstalk", i, "nominal")] = _cell("crosstalk", i, "nominal", [5 + i / 2, 7 + i / 2],
                                                              [20.0 - 2 * i, 22.0 - 2 * i])  # fmt: skip
        cells[rb.cell_key("crosstalk", i, "true")] = _cell("crosstalk", i, "true", [5.0, 7.0], [20.0, 22.0])
    d = rr.paired_difference(cells["crosstalk-3-nominal"], cells["nominal"], "normal_mae")
    assert d["mean"] == pytest.approx(1.5) and d["ci"] == pytest.approx([1.5, 1.5])
    table = rr.sweep_table(cells)
    assert "| 0.1 | nominal | 7.50 [" in table and "+1.50 [+1.50, +1.50]" in table
    tol = rr.tolerance_table(cells)
    # Level 2 (0.05) gives exactly +1.0 deg: the normal tolerance is 0.05.
    row = next(line for line in tol.splitlines() if "| nominal |" in line and "cross-talk" in line)
    assert row.split("|")[3].strip() == "0.05"
    assert row.split("|")[4].strip() == "0.01"  # -1 dB halfway to the first level (0.02): lower PSNR is worse
    assert "> 0.15" in next(line for line in tol.splitlines() if "| true |" in line)
    other = _cell("crosstalk", 1, "nominal", [5.0], [20.0], scenes=(3,))
    with pytest.raises(ValueError, match="different scenes"):
        rr.paired_difference(other, cells["nominal"], "normal_mae")


def test_tolerance_interpolates_between_levels():
    assert rr.tolerance([0.0, 2.0, 4.0], [0.0, 0.5, 1.5], 1.0) == pytest.approx(3.0)
    assert rr.tolerance([100.0, 50.0, 20.0], [0.0, 2.0, 3.0], 1.0) == pytest.approx(75.0)  # falling levels
    assert rr.tolerance([0.0, 1.0], [0.0, None], 1.0) is None
