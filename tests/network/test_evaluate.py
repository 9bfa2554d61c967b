"""Tests of network/evaluate.py: Table 1 / Table 3 on a tiny rendered dataset with a toy checkpoint, the CLI.

The CLI is headless/evaluate.py, a thin layer over :func:`network.evaluate.evaluate`.
"""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from network import metrics

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """Two rendered samples and a toy checkpoint trained for two steps."""
    pytest.importorskip("mitsuba")
    from blender_addon.core.generate import GenerateConfig, generate
    from network.train import TrainConfig, train

    root = tmp_path_factory.mktemp("eval")
    data = root / "data"
    assert len(generate(GenerateConfig(out=data, count=2, resolution=32, spp=4, seed=11), progress=False).written) == 2
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        train(TrainConfig(data=data, out=root / "run", steps=2, checkpoint_every=2), progress=False)
    finally:
        torch.set_num_threads(threads)
    return {"data": data, "ckpt": root / "run" / "model.pt", "root": root}


def _variant_checkpoint(bench, variant):
    """The toy checkpoint relabelled as trained with ``variant`` (what `train.py --inputs` writes)."""
    path = bench["root"] / f"{variant}.pt"
    if not path.exists():
        ckpt = torch.load(bench["ckpt"], weights_only=True)
        torch.save({**ckpt, "inputs": variant}, path)
    return path


@pytest.mark.mitsuba
def test_table1_and_baseline_row(bench, tmp_path):
    from network import baseline, evaluate
    from network.checkpoint import load_checkpoint
    from network.infer import predict
    from pbrdf.data import dataset as pdataset

    result = evaluate.evaluate(bench["ckpt"], bench["data"])
    assert result["ours"] == "full" and set(result["methods"]) == {"full", "baseline"}
    base, ours = result["methods"]["baseline"], result["methods"]["full"]
    model, ckpt = load_checkpoint(bench["ckpt"])
    assert ckpt["input_scale"] == "calibrated"  # the training default
    maes, pix = [], []
    for row_b, row_o in zip(base["per_sample"], ours["per_sample"], strict=True):
        sample, meta = pdataset.read_sample(bench["data"], row_b["index"])
        mask = sample["mask"]
        # The row is the public baseline on the sample's mask, calibrated from the sample's own rig.
        ps = baseline.predict_sample(sample["maps"], mask, meta)
        mae = metrics.normal_mae_deg(ps["normal"], sample["normal"], mask)
        assert row_b["normal_mae"] == pytest.approx(mae, rel=1e-9)
        if result["lpips"]["available"]:
            assert row_b["albedo_lpips"] == pytest.approx(metrics.lpips(ps["albedo"], sample["albedo"], mask))
        assert row_b["roughness_rmse"] is None and row_b["metallic_rmse"] is None
        assert row_b["pixels"] == int(mask.sum())
        maes.append(mae)
        pix.append(mask.sum())
        radiance = meta["rig"]["display"]["radiance"]
        pred = predict(model, sample["maps"], mask, input_scale="calibrated", radiance=radiance)
        assert row_o["normal_mae"] == pytest.approx(metrics.normal_mae_deg(pred["normal"], sample["normal"], mask))
        assert row_o["metallic_rmse"] == pytest.approx(
            metrics.rmse(pred["metallic"], sample["metallic"][..., None], mask)
        )
    assert base["mean"]["normal_mae"] == pytest.approx(np.average(maes, weights=pix))
    d = result["vs_baseline"]
    assert d["normal_mae"] == pytest.approx(ours["mean"]["normal_mae"] - base["mean"]["normal_mae"])
    assert d["roughness_rmse"] is None
    if result["lpips"]["available"]:
        lp = [r["albedo_lpips"] for r in base["per_sample"]]
        assert base["mean"]["albedo_lpips"] == pytest.approx(np.average(lp, weights=pix))

    files = evaluate.write_results(result, tmp_path / "out")
    assert sorted(f.name for f in files) == ["metrics.json", "table1.md", "table3.md"]
    table1 = (tmp_path / "out" / "table1.md").read_text()
    lines = [ln for ln in table1.splitlines() if ln.startswith("|")]
    assert lines[0].split("|")[1:-1] == [" Method ", *(f" {h} " for _, h, _ in evaluate.COLUMNS)]
    assert lines[2].startswith("| Photometric stereo (baseline) |") and lines[3].startswith("| Ours |")
    assert lines[4].startswith("| Ours vs baseline |") and "vs baseline:" in table1
    verdict = "better" if ours["mean"]["normal_mae"] < base["mean"]["normal_mae"] else "worse"
    assert f"Normal MAE (deg) {verdict} by {abs(d['normal_mae']):.4g}" in table1
    assert f"{base['mean']['normal_mae']:.2f}" in lines[2] and lines[2].count("n/a") == 2
    loaded = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert loaded["methods"]["baseline"]["mean"]["normal_mae"] == pytest.approx(base["mean"]["normal_mae"])


@pytest.mark.mitsuba
def test_table3_ablation_applies_each_variant(bench, tmp_path):
    from network import evaluate
    from network.checkpoint import load_checkpoint
    from network.infer import predict
    from pbrdf.data import dataset as pdataset

    ckpts = {"polar": _variant_checkpoint(bench, "polar"), "spectral": _variant_checkpoint(bench, "spectral"),
             "full": bench["ckpt"]}  # fmt: skip
    result = evaluate.evaluate(ckpts, bench["data"], limit=1)
    assert set(result["methods"]) == {"polar", "spectral", "full", "baseline"}
    model, _ = load_checkpoint(bench["ckpt"])
    sample, _ = pdataset.read_sample(bench["data"], result["methods"]["polar"]["per_sample"][0]["index"])
    maps, mask = sample["maps"].copy(), sample["mask"]
    maps[..., 6:] = 0  # no CP: what the 'polar' variant sees (zeroed here independently of apply_inputs)
    pred = predict(model, maps, mask, input_scale="calibrated", radiance=1.0)  # the default rig's display
    want = metrics.normal_mae_deg(pred["normal"], sample["normal"], mask)
    assert result["methods"]["polar"]["mean"]["normal_mae"] == pytest.approx(want, rel=1e-6)
    assert result["methods"]["polar"]["mean"]["normal_mae"] != result["methods"]["full"]["mean"]["normal_mae"]
    table3 = evaluate.table3_markdown(result)
    rows = [ln for ln in table3.splitlines() if ln.startswith("| ")][1:]
    assert [r.split("|")[1].strip() for r in rows] == list(evaluate.VARIANT_LABELS.values())
    assert rows[0].count("—") == len(evaluate.COLUMNS) and "No checkpoint for: white" in table3
    assert "—" not in rows[1] + rows[2] + rows[3]

    with pytest.raises(ValueError, match="'white' variant needs data rendered with the white display pattern"):
        evaluate.evaluate({"white": _variant_checkpoint(bench, "white")}, bench["data"])
    with pytest.raises(ValueError, match="variant 'white' needs white data"):
        evaluate.evaluate({"white": _variant_checkpoint(bench, "white")}, bench["data"], white_data=bench["data"])
    with pytest.raises(ValueError, match="trained with inputs 'polar', given as 'full'"):
        evaluate.evaluate({"full": ckpts["polar"]}, bench["data"])
    with pytest.raises(ValueError, match="unknown input variant 'cp'"):
        evaluate.evaluate({"cp": bench["ckpt"]}, bench["data"])


@pytest.mark.mitsuba
def test_lpips_columns_say_why_without_weights(bench, tmp_path, monkeypatch):
    from network import evaluate

    monkeypatch.setenv("PDIR_LPIPS_WEIGHTS", str(tmp_path / "none.ckpt"))
    result = evaluate.evaluate(bench["ckpt"], bench["data"], limit=1)
    assert result["lpips"] == {"available": False, "reason": f"{tmp_path / 'none.ckpt'}: LPIPS weight file not found"}
    assert result["methods"]["full"]["mean"]["albedo_lpips"] is None
    assert result["methods"]["full"]["mean"]["albedo_psnr"] is not None
    table1 = evaluate.table1_markdown(result)
    row = next(ln for ln in table1.splitlines() if ln.startswith("| Ours |")).split("|")[1:-1]
    assert row[3].strip() == "n/a" and row[5].strip() == "n/a" and row[2].strip() != "n/a"
    assert "LPIPS n/a: " in table1 and "none.ckpt: LPIPS weight file not found" in table1


@pytest.mark.mitsuba
def test_real_data_rerendering_error(bench):
    from network import evaluate
    from network.checkpoint import load_checkpoint
    from network.inputs import apply_inputs

    result = evaluate.evaluate(bench["ckpt"], bench["data"], limit=1, real=bench["data"])
    real = result["real"]
    if importlib.util.find_spec("network.realdata") is None:
        assert "network.realdata" in real["skipped"] and "not available yet" in real["skipped"]
        assert "skipped" in evaluate.real_markdown(result)
        return
    from network.realdata import RealDataset
    from network.rerender import Patches, rerender_dense

    # The same error computed here step by step from network.rerender's and network.realdata's pieces.
    model, _ = load_checkpoint(bench["ckpt"])
    item = RealDataset(bench["data"], model.config.image_size)[0]
    b = {k: v[None] for k, v in item.items()}
    with torch.no_grad():
        pred = model(apply_inputs(b["maps"], "full"), b["mask"])
        sim = rerender_dense(pred, b["mask"], b["points"], Patches.unpack(b["patches"]))
    sim = torch.cat([sim["unpol"], sim["lp"]], 1)[0].permute(1, 2, 0).numpy()
    meas = b["maps"][0, :6].permute(1, 2, 0).numpy()
    mask = b["mask"][0, 0].numpy() > 0
    row = real["full"]["per_sample"][0]
    assert row["si_rmse"] == pytest.approx(metrics.si_rmse(sim, meas, mask), rel=1e-6)
    assert row["si_mse"] == pytest.approx(row["si_rmse"] ** 2, rel=1e-9)
    assert row["si_psnr"] == pytest.approx(20 * np.log10(row["peak"] / row["si_rmse"]), rel=1e-6)
    assert row["peak"] == pytest.approx(np.quantile(meas[mask], 0.99))
    if result["lpips"]["available"]:  # the unpol RGB image, brightness-normalised by the capture's peak
        peak = row["peak"]
        want = metrics.si_lpips(sim[..., :3], meas[..., :3], mask, peak=peak)
        assert row["si_lpips"] == pytest.approx(want, rel=1e-5)
        assert metrics.si_lpips(meas[..., :3], meas[..., :3], mask, peak=peak) == pytest.approx(0.0, abs=1e-6)
        assert row["si_lpips"] > 1e-4  # an untrained model does not re-render the capture exactly
    assert "| + CP (ours) |" in evaluate.real_markdown(result)


def _cli(*args):
    return subprocess.run([sys.executable, str(ROOT / "headless" / "evaluate.py"), *map(str, args)],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)  # fmt: skip


def _main():
    spec = importlib.util.spec_from_file_location("evaluate_cli", ROOT / "headless" / "evaluate.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.main


@pytest.mark.mitsuba
def test_cli(bench, tmp_path):
    out = tmp_path / "ev"
    r = _cli("--checkpoint", bench["ckpt"], "--input", bench["data"], "--out", out, "--limit", "1", "--quiet")
    assert r.returncode == 0, r.stderr
    assert "| Photometric stereo (baseline) |" in r.stdout and "| Ours |" in r.stdout
    assert {p.name for p in out.iterdir()} == {"metrics.json", "table1.md", "table3.md"}
    assert json.loads((out / "metrics.json").read_text())["methods"]["full"]["count"] == 1


@pytest.mark.mitsuba
def test_cli_help_and_one_line_errors(bench, tmp_path, capsys):
    main = _main()
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0 and "table1.md" in capsys.readouterr().out
    for args, msg in [
        (("--checkpoint", bench["ckpt"], "--input", tmp_path / "missing"), "dataset folder not found"),
        (("--checkpoint", tmp_path / "no.pt", "--input", bench["data"]), "checkpoint not found"),
        (("--checkpoint", f"full={bench['ckpt']}", "--checkpoint", "oops", "--input", bench["data"]), "VARIANT=PATH"),
        (("--checkpoint", f"rgb={bench['ckpt']}", "--input", bench["data"]), "unknown input variant 'rgb'"),
        (("--checkpoint", bench["ckpt"], "--input", bench["data"], "--limit", "0"), "limit must be >= 1"),
    ]:
        assert main([*map(str, args), "--quiet"]) == 2, args
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ") and msg in err[0], err
