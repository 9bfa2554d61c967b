"""network/rerender_error.py: the re-rendering error on real captures, step by step from its pieces."""

import numpy as np
import pytest
import torch

from network import metrics


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """Two rendered samples read as real captures."""
    pytest.importorskip("mitsuba")
    from blender_addon.core.generate import GenerateConfig, generate

    root = tmp_path_factory.mktemp("real")
    assert len(generate(GenerateConfig(out=root, count=2, resolution=32, spp=4, seed=11), progress=False).written) == 2
    return root


@pytest.mark.mitsuba
def test_rerendering_error_of_the_first_capture(captures):
    from network.checkpoint import load_checkpoint
    from network.infer import DEFAULT_CHECKPOINT
    from network.inputs import apply_inputs
    from network.realdata import RealDataset
    from network.rerender import Patches, rerender_dense
    from network.rerender_error import rerender_error, rerender_markdown

    model, ckpt = load_checkpoint(DEFAULT_CHECKPOINT)
    result = rerender_error(model, "full", captures, limit=1)
    assert len(result["per_sample"]) == 1
    # The same error computed here from network.rerender's and network.realdata's pieces.
    item = RealDataset(captures, model.config.image_size)[0]
    b = {k: v[None] for k, v in item.items()}
    with torch.no_grad():
        pred = model(apply_inputs(b["maps"], "full"), b["mask"])
        sim = rerender_dense(pred, b["mask"], b["points"], Patches.unpack(b["patches"]))
    sim = torch.cat([sim["unpol"], sim["lp"]], 1)[0].permute(1, 2, 0).numpy()
    meas = b["maps"][0, :6].permute(1, 2, 0).numpy()
    mask = b["mask"][0, 0].numpy() > 0
    row = result["per_sample"][0]
    assert row["si_rmse"] == pytest.approx(metrics.si_rmse(sim, meas, mask), rel=1e-6)
    assert row["si_mse"] == pytest.approx(row["si_rmse"] ** 2, rel=1e-9)
    assert row["si_psnr"] == pytest.approx(20 * np.log10(row["peak"] / row["si_rmse"]), rel=1e-6)
    assert row["peak"] == pytest.approx(np.quantile(meas[mask], 0.99))
    assert result["mean"]["si_rmse"] == pytest.approx(row["si_rmse"])  # one capture: its own mean
    if row["si_lpips"] is not None:  # the unpol RGB image, brightness-normalised by the capture's peak
        want = metrics.si_lpips(sim[..., :3], meas[..., :3], mask, peak=row["peak"])
        assert row["si_lpips"] == pytest.approx(want, rel=1e-5)
        assert metrics.si_lpips(meas[..., :3], meas[..., :3], mask, peak=row["peak"]) == pytest.approx(0.0, abs=1e-6)
    assert "| Ours |" in rerender_markdown(result, "Ours")
    assert "skipped" in rerender_error(model, "white", captures)  # captured under the RGB pattern
