"""Diagnose a metallic drift: does refitting only the metallic output row on frozen features recover it?

    python tools/metallic_row_refit.py --checkpoint out/runs/light-replay-plain/best.pt [--scenes 60]

Last-layer retraining: the model's per-pixel features (the input of ``brdf_head.fc2``) are collected at
2048 sampled object pixels of the first ``--scenes`` scenes of each training folder (``--train``) and of
every validation scene (``--val``); the metallic row of ``fc2`` (weight and bias) is then refitted by
L-BFGS to the same L2 loss training uses, on the training pixels only. Prints the pixel RMSE of the
metallic prediction on every folder before and after. If the refit does not lower the validation RMSE,
the drift lives in the features, not the last layer. Reads no test split.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from network.checkpoint import load_checkpoint  # noqa: E402
from network.data import gather_pixels  # noqa: E402
from network.inputs import apply_inputs  # noqa: E402
from network.packed import open_samples  # noqa: E402
from network.schedules import sample_batch_pixels  # noqa: E402


def collect(model, ckpt: dict, folder: str, count: int, seed: int = 777) -> tuple[torch.Tensor, torch.Tensor]:
    """Features (N, hidden) at the metallic head's last layer and the true metallic (N,) of sampled pixels."""
    light_input = bool(ckpt["config"].get("light_input", False))
    ds = open_samples(folder, size=ckpt["config"].get("image_size", 192), input_scale=ckpt["input_scale"],
                      light_input=light_input)  # fmt: skip
    feats: list[torch.Tensor] = []
    hook = model.decoder.brdf_head.fc2.register_forward_hook(
        lambda _m, args, _o: feats.append(args[0].detach().reshape(-1, args[0].shape[-1]).float())
    )
    rows, truth = [], []
    try:
        for k in range(min(count, len(ds))):
            item = ds[k]
            pixels, valid = sample_batch_pixels(item["mask"][None], 2048, [seed + k])
            light = item["light"][None] if light_input else None
            feats.clear()
            with torch.no_grad():
                maps = apply_inputs(item["maps"][None], ckpt["inputs"])
                model.decode_pixels(model.encode(maps, item["mask"][None], light), maps, pixels, valid, light)
            keep = valid[0].bool().reshape(-1)
            rows.append(torch.cat(feats)[keep])
            truth.append(gather_pixels(item["metallic"][None], pixels)[0, 0][keep])
    finally:
        hook.remove()
    return torch.cat(rows), torch.cat(truth)


def rmse(h: torch.Tensor, m: torch.Tensor, w: torch.Tensor, b: torch.Tensor) -> float:
    """Pixel RMSE of sigmoid(h w + b) against m."""
    return float(((torch.sigmoid(h @ w + b) - m) ** 2).mean().sqrt())


def main(argv: list[str] | None = None) -> int:
    """Collect, refit and print (the command line above)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", required=True, help="model.pt / best.pt to diagnose")
    ap.add_argument("--train", nargs="+", default=["out/splits/train-light", "out/splits/train-engine-plain"],
                    help="training folders the row is refitted on")  # fmt: skip
    ap.add_argument("--val", default="out/splits/val-light", help="validation folder (scored, never fitted)")
    ap.add_argument("--scenes", type=int, default=60, help="scenes per training folder")
    args = ap.parse_args(argv)
    torch.manual_seed(0)
    model, ckpt = load_checkpoint(args.checkpoint)
    sets = {f: collect(model, ckpt, f, args.scenes) for f in args.train}
    sets[args.val] = collect(model, ckpt, args.val, 10**9)
    fc2 = model.decoder.brdf_head.fc2
    w0, b0 = fc2.weight[4].detach().clone(), fc2.bias[4].detach().clone()
    h = torch.cat([sets[f][0] for f in args.train])
    m = torch.cat([sets[f][1] for f in args.train])
    w, b = w0.clone().requires_grad_(), b0.clone().requires_grad_()
    opt = torch.optim.LBFGS([w, b], max_iter=200, line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        opt.zero_grad()
        loss = ((torch.sigmoid(h @ w + b) - m) ** 2).mean()
        loss.backward()
        return loss

    opt.step(closure)
    print(f"{args.checkpoint}: metallic pixel RMSE, before -> after refitting the row on {', '.join(args.train)}")
    for name, (hf, mf) in sets.items():
        role = "val" if name == args.val else "train"
        print(f"  {role:5s} {name}: {rmse(hf, mf, w0, b0):.4f} -> {rmse(hf, mf, w.detach(), b.detach()):.4f} "
              f"({len(mf)} pixels)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
