"""network.demo.pipeline: the demo's configuration and its small helpers (the full run: tests/headless/test_demo.py)."""

import numpy as np
import pytest

from network.demo import DemoConfig, pipeline


@pytest.mark.parametrize(
    "changes",
    [{"scenes": 0}, {"scenes": 2, "measured_scenes": 3}, {"resolution": 8}, {"spp": 0}, {"relight_frames": -1}],
)
def test_config_rejects_bad_sizes(changes):
    with pytest.raises(ValueError):
        DemoConfig(**changes)


def test_relight_script_exists_beside_the_package():
    from network.demo.relight_compare import RELIGHT_SCRIPT

    assert RELIGHT_SCRIPT.is_file()


def test_demo_rows_are_summarised_per_scene_and_pixel_weighted():
    # The demo's table comes from network.evaluation.summarize_rows, like headless/evaluate.py.
    from network.evaluation import METHODS, METRICS, summarize_rows

    def row(pixels, mae):
        scores = {k: None for k, _, _ in METRICS}
        return {"pixels": pixels, "mask_iou": 0.9, **{m: {**scores, "normal_mae": mae} for m in METHODS}}

    out = summarize_rows([row(1, 1.0), row(3, 3.0)])
    mae = out["methods"]["ours"]["normal_mae"]
    assert mae["mean"] == pytest.approx(2.0) and mae["weighted_mean"] == pytest.approx(2.5)
    assert out["methods"]["ours"]["roughness_rmse"]["mean"] is None


def test_angle_map_degrees():
    from network.demo.figures import angle_map

    a = np.array([[[1.0, 0, 0], [0, 1.0, 0]]])
    b = np.array([[[0, 1.0, 0], [0, 2.0, 0]]])
    out = angle_map(a, b, np.array([[True, True]]))
    np.testing.assert_allclose(out, [[90.0, 0.0]], atol=1e-6)


def test_expansion_figures_get_captions_not_file_names(tmp_path):
    from network.demo.report import placeholder_caption

    (tmp_path / "pbrdfs").mkdir()
    (tmp_path / "pbrdfs" / "manifest.json").write_text('{"seeds": [{}, {}, {}], "count": 12}')
    (tmp_path / "pbrdfs" / "figure_seeds.png").write_bytes(b"")
    (tmp_path / "pbrdfs" / "figure_generated.png").write_bytes(b"")
    figs = dict(pipeline._expansion_figures(tmp_path))
    assert set(figs) == {"pbrdfs/figure_seeds.png", "pbrdfs/figure_generated.png"}
    for rel, caption in figs.items():
        assert not placeholder_caption(rel, caption), caption
    assert figs["pbrdfs/figure_seeds.png"].startswith("All 3 seed materials")
    assert figs["pbrdfs/figure_generated.png"].startswith(f"{pipeline.FIGURE_TABLES} of the pBRDF tables")


@pytest.mark.bpy
@pytest.mark.slow  # three Blender processes
def test_relight_stage_scores_the_constant_predictor_beside_the_prediction(tmp_path):
    """The demo's relight stage (tiny frames, real bpy processes): the constant predictor relit and scored too."""
    pytest.importorskip("bpy")
    from types import SimpleNamespace

    from network.constant import constant_predict
    from tests.gltf_helpers import sphere_prediction

    k = np.array([[40.0, 0.0, 16.0], [0.0, 40.0, 16.0], [0.0, 0.0, 1.0]])
    truth = sphere_prediction(np.random.default_rng(0), k, 32, 32, bumps=False, centre=(0, 0, -0.9), radius=0.25)
    region = truth["mask"][..., 0] > 0
    ours = {key: truth[key] for key in ("normal", "albedo", "roughness", "metallic", "mask")}  # a perfect prediction
    ours["mask"], ours["normal"] = ours["mask"].copy(), ours["normal"].copy()
    ours["mask"][16, 0], ours["normal"][16, 0] = 1.0, (0, 0, 1)  # but one pixel outside the object: the constant
    # asset must take the prediction's mask (a unit normal on every one of its pixels), not the truth's
    stats = {"albedo": [0.5, 0.5, 0.5], "roughness": 0.5, "metallic": 0.0}
    scene = SimpleNamespace(ours=ours, gt=truth, region=region, intrinsics=k,
                            preds={"constant": constant_predict(stats, region)})  # fmt: skip
    pipeline._write_assets(tmp_path, "ball", scene)
    assert (tmp_path / "constant" / "ball" / "ball_depth.exr").is_file()
    cfg = DemoConfig(out=tmp_path, relight_frames=1, relight_size=32, relight_samples=2)
    results = pipeline._Results()
    pipeline._relight(cfg, tmp_path, {"ball": scene}, results)
    names = sorted(p.name for p in (tmp_path / "relit_constant" / "ball").glob("*.png"))
    assert names == sorted(p.name for p in (tmp_path / "relit_truth" / "ball").glob("*.png")) and len(names) == 2
    (row,) = results.relight_rows
    # the prediction is the truth (its relief integrated from the true normals): far above the flat grey constant
    assert row["constant"]["psnr"] is not None and row["psnr"] > row["constant"]["psnr"] + 3, row
    assert pipeline._relight_table(results.relight_rows)[0][3] == row["constant"]["psnr"]
