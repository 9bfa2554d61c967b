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
