"""network/bench/fullframe.py: the stage profile of a capture and the stride error against stride 1."""

from pathlib import Path

import numpy as np
import pytest

from network.bench.fullframe import TOLERANCE, profile, stride_error

ROOT = Path(__file__).resolve().parents[3]
# The profile times the relief and the map writes as one stage: infer.py overlaps them (headless._overlap).
RELIEF = "relief depth integration, the maps written (EXR + PNG) meanwhile"


def _rotated(normal: np.ndarray, deg: float) -> np.ndarray:
    """Normals turned by ``deg`` about the x axis (an independent rotation, not the error's own formula)."""
    a = np.radians(deg)
    rot = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
    return normal @ rot.T


def _maps(rng: np.random.Generator) -> dict:
    n = rng.normal(size=(20, 30, 3)) + [0.0, 0.0, 4.0]
    return {
        "normal": n / np.linalg.norm(n, axis=-1, keepdims=True),
        "albedo": rng.uniform(0, 1, (20, 30, 3)),
        "roughness": rng.uniform(0, 1, (20, 30, 1)),
        "metallic": rng.uniform(0, 1, (20, 30, 1)),
    }


def test_stride_error_measures_angles_and_rmse():
    ref = _maps(np.random.default_rng(0))
    mask = np.ones((20, 30), bool)
    mask[:, :5] = False
    turned = dict(ref, normal=_rotated(ref["normal"], 0.8))
    err = stride_error(ref, turned, mask)
    # v and Rv are 0.8 deg apart where v is normal to the axis; these normals lean at most ~35 deg toward it
    assert 0.6 < err["normal_deg_p99"] <= 0.8 + 1e-6 and err["albedo_rmse"] == 0.0 and err["within"]
    brighter = dict(ref, albedo=ref["albedo"] + np.where(mask[..., None], 0.0, 1.0))  # only outside the mask
    assert stride_error(ref, brighter, mask)["albedo_rmse"] == 0.0
    off = dict(ref, roughness=ref["roughness"] + 2 * TOLERANCE["brdf_rmse"])
    err = stride_error(ref, off, mask)
    assert err["roughness_rmse"] == pytest.approx(2 * TOLERANCE["brdf_rmse"]) and not err["within"]
    assert not stride_error(ref, dict(ref, normal=_rotated(ref["normal"], 1.5)), mask)["within"]


def test_profile_times_every_stage_of_the_example_capture():
    checkpoint = ROOT / "models" / "small" / "model.pt"
    result = profile(ROOT / "examples" / "capture", checkpoint, stride=2)
    stages = result["stages"]
    named = ("read the raw brackets", "decode the nine maps", "encoder (crop resized to the input size)",
             "per-pixel decoder", RELIEF, "glTF binary")  # fmt: skip
    for name in named:
        assert stages[name] > 0, name
    assert all(s >= 0 for s in stages.values())
    assert sum(stages.values()) <= result["total_seconds"] * 1.001
    assert result["frame"]["raw"][1:] == [256, 256] and result["frame"]["decoded"] == [128, 128]
    assert 0 < result["frame"]["masked_share"] < 1 and result["table"].count("\n") == len(stages) + 1


def test_identical_float32_normals_are_zero_degrees_apart():
    ref = {k: v.astype(np.float32) for k, v in _maps(np.random.default_rng(1)).items()}
    err = stride_error(ref, ref, np.ones((20, 30), bool))
    assert err["normal_deg_max"] == 0.0 and err["within"]


def test_depth_error_reads_the_angle_between_two_planes():
    """Two planes 2 deg apart (ray-plane intersections, not the error's own formula) read as 2 deg."""
    from network.bench.fullframe import depth_error
    from pbrdf.sensor.projection import pinhole_intrinsics, pixel_rays

    k = pinhole_intrinsics(200.0, 40, 30)
    rays = pixel_rays(k, 30, 40)

    def plane(normal):
        n = np.asarray(normal) / np.linalg.norm(normal)
        return (np.array([0.0, 0.0, -0.7]) @ n) / (rays @ n)

    a = np.radians(2.0)
    ref, got = plane([0.2, 0.0, 1.0]), plane([0.2, np.sin(a), np.cos(a)])
    mask = np.ones((30, 40), bool)
    e = depth_error(ref, got, mask, k)
    assert 1.7 < e["surface_deg_p50"] < 2.3 and e["depth_rel_max"] > 0.01
    same = depth_error(ref, ref.copy(), mask, k)
    assert same["surface_deg_p99"] < 1e-6 and same["depth_rel_max"] == 0.0


def test_depth_rows_compares_the_two_preconditioners_on_the_example_capture():
    from network.bench.fullframe import depth_rows

    result = depth_rows(ROOT / "examples" / "capture", ROOT / "models" / "small" / "model.pt", repeat=1)
    assert set(result["rows"]) == {"two_grid", "multigrid"} and result["masked_pixels"] > 0
    assert all(r["wall_median"] > 0 and r["cpu_median"] > 0 for r in result["rows"].values())
    assert result["two_grid_vs_multigrid"]["depth_rel_max"] < 1e-3
