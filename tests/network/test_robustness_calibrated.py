"""network/robustness_calibrated.py and its report: perturbed rigs, the calibrated decoder, the verdicts.

The decoder on rendered scenes with the shipped model (headless/robustness.py --cases) is tested in
tests/headless/test_robustness.py.
"""

import math

import numpy as np
import pytest

from network import robustness_calibrated as rc
from network import robustness_report as rr
from network.infer import load_input
from pbrdf.data import capture as pcapture
from pbrdf.sensor.camera import CameraModel, simulate_capture
from pbrdf.sensor.imperfections import vignetting_map
from pbrdf.sensor.rig import Rig


def test_worst_case_sets_every_term_at_its_last_level():
    rig = rc.perturbed_rig("worst", Rig(), (64, 96))
    m = rig.camera.model
    assert np.allclose(m.crosstalk, [[1, 0.15, 0.075], [0.15, 1, 0.15], [0.075, 0.15, 1]])
    assert m.ambient == pytest.approx((0.1,) * 3) and m.extinction_ratio == (20.0,) * 3
    assert m.qwp_retardance == pytest.approx((math.radians(100.0),) * 3) and m.qwp_angle == pytest.approx(
        math.radians(5.0)
    )
    assert vignetting_map((64, 96), m.vignetting_focal_px, m.vignetting_poly)[0, 0] == pytest.approx(0.7)
    assert rig.display.degree_of_polarization == 0.9
    assert rig.display.polarization_angle == pytest.approx(math.radians(95.0))
    jitter = rc.perturbed_rig("jitter2-a", Rig(), (64, 64))
    assert jitter.camera.model != Rig().camera.model and jitter == rc.perturbed_rig("jitter2-a", Rig(), (64, 64))
    with pytest.raises(ValueError, match="case must be one of"):
        rc.perturbed_rig("best", Rig(), (64, 64))


#: A planted rig: the camera terms that decoding can undo, each large.
TERMS = (("crosstalk", 0.15), ("ambient", 0.05), ("qwp_retardance", 10.0), ("qwp_angle", 5.0), ("extinction", 20.0),
         ("vignetting", 0.3))  # fmt: skip
PLANTED = rc.RigCase("planted", "planted", TERMS, seed=5)


def _basis(rng, shape=(64, 64)):
    """A smooth partly polarized scene under the display at 90, 0 and 45 degrees (a Mueller scene by hand)."""
    s0 = 0.03 + 0.05 * rng.random((*shape, 3))
    m = np.zeros((*shape, 3, 4, 4))  # a diattenuator-like reflection: s0' = s0 (a + b s1), s1' = s0 (b + a s1) ...
    m[..., 0, 0] = m[..., 1, 1] = s0
    m[..., 0, 1] = m[..., 1, 0] = 0.4 * s0
    m[..., 2, 2] = m[..., 3, 3] = 0.6 * s0
    m[..., 3, 2] = 0.3 * s0  # some circular polarization from the display's s2
    emitted = {k: np.array([1.0, math.cos(2 * a), math.sin(2 * a), 0.0])
               for k, a in (("v", math.pi / 2), ("h", 0.0), ("d", math.pi / 4))}  # fmt: skip
    return {k: m @ e for k, e in emitted.items()}


def test_calibrated_decoder_recovers_what_the_true_rig_decodes(rng, tmp_path):
    basis = _basis(rng)
    up = np.repeat(np.repeat(basis["v"], 2, axis=0), 2, axis=1)
    nominal = CameraModel()
    cap = pcapture.Capture(raws=simulate_capture(up, nominal, rng=np.random.default_rng([9, 1])), model=nominal)
    ref = load_input(pcapture.save_capture(tmp_path / "ref", cap.raws, nominal)).maps  # the unperturbed rig
    true = rc.perturbed_rig(PLANTED, Rig(camera=Rig().camera), cap.raws.shape[1:])
    est, errors = rc.calibrate_rig(true, cap.raws.shape[1:], PLANTED.seed)
    assert errors["crosstalk"] < 5e-3 and errors["qwp_retardance"] < 6e-3  # docs/calibration.md's tolerances
    maps = {}
    for decoder in rc.CAL_DECODERS:
        folder = rc.case_capture(tmp_path / decoder, basis, cap, 9, true, decoder)
        assert (pcapture.load_capture(folder).dark is None) == (decoder == "nominal")
        maps[decoder] = load_input(folder, rig=est if decoder == "calibrated" else None).maps
    err = {d: np.abs(maps[d] - ref)[..., :6].mean() for d in maps}  # unpolarized and linear maps
    # The calibrated decode is as close to the unperturbed one as the true rig's, the nominal one far off.
    assert err["calibrated"] < 1.2 * err["true"] + 1e-4, err
    assert err["calibrated"] < 0.2 * err["nominal"], err


def _cell(key_case, decoder, normal, psnr, scenes=(0, 1, 2)):
    rows = [{"index": i, "pixels": 100, "mask_iou": 0.9,
             "ours": {"normal_mae": n, "albedo_psnr": p, "roughness_rmse": 0.1, "metallic_rmse": 0.05}}
            for i, n, p in zip(scenes, normal, psnr, strict=True)]  # fmt: skip
    from network.robustness import _summary

    return {"case": key_case, "decoder": decoder, "scenes": list(scenes), "rows": rows, "summary": _summary(rows)}


def test_verdicts_read_the_unperturbed_interval_and_the_paired_change():
    cells = {
        rc.UNPERTURBED: _cell("unperturbed", "nominal", [5.0, 9.0, 7.0], [20.0, 22.0, 24.0]),
        "worst-calibrated": _cell("worst", "calibrated", [5.5, 9.5, 7.5], [20.0, 22.0, 24.0]),
        "worst-true": _cell("worst", "true", [5.4, 9.4, 7.4], [20.0, 22.0, 24.0]),
        "worst-nominal": _cell("worst", "nominal", [15.0, 19.0, 17.0], [15.0, 17.0, 19.0]),
    }
    text = rr.calibration_verdicts(cells)
    normal = next(line for line in text.splitlines() if "| worst | normal MAE" in line).split("|")
    # Mean 7.5 is inside the unperturbed interval of [5, 9, 7]; the paired change is +0.5 on every scene.
    assert normal[5].strip() == "yes" and normal[6].strip() == "+0.50 [+0.50, +0.50]" and normal[7].strip() == "no"
    assert normal[8].strip() == "+0.10 [+0.10, +0.10]" and normal[9].strip() == "+10.00 [+10.00, +10.00]"
    psnr = next(line for line in text.splitlines() if "| worst | albedo PSNR" in line).split("|")
    assert psnr[5].strip() == "yes" and psnr[7].strip() == "yes"
    table = rr.calibration_table(cells)
    assert table.splitlines()[2].startswith("| unperturbed | - | 7.00 [") and "| worst | nominal | 17.00 [" in table
    pooled = rr.pool_cells({"a": cells, "b": cells})
    assert pooled["worst-nominal"]["scenes"][:4] == ["a:0", "a:1", "a:2", "b:0"]
    assert pooled["worst-nominal"]["summary"]["normal_mae"]["count"] == 6
