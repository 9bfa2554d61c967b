"""Model presets side by side: parameters, checkpoint size in float32 and bfloat16, CPU inference time, decoder share.

    PYTHONPATH=. python tools/preset_size.py [--configs small medium] [--size 384] [--repeat 3] [--out FILE]

Per preset: parameters; the bytes of ``torch.save`` of its state dict in float32 and in bfloat16 (what a
``model.pt`` holds, less a few hundred bytes of settings); the encoder (``model.encode``) and the stride-1
dense decoder (``model.decode_dense`` on the cached features) at ``--size`` on smooth maps with a disc mask
over half the image (:func:`network.bench.model.smooth_input`; randomly initialised weights: cost only),
and the decoder's share of their sum. The presets alternate within each repeat, so both see the same load.
With ``--checkpoint`` (default: the shipped model): its predictions (:func:`network.infer.predict`) on
``examples/capture`` with its weights rounded to bfloat16 (as a bf16 ``model.pt`` would load them)
against float32: the normal angle and the BRDF differences inside the mask. JSON on stdout (and --out).
"""

from __future__ import annotations

import argparse
import io
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _bytes(state: dict) -> int:
    import torch  # noqa: PLC0415

    buf = io.BytesIO()
    torch.save(state, buf)
    return buf.tell()


def presets(names: list[str], size: int, repeat: int) -> dict:
    """Parameters, checkpoint bytes and median encode/decode seconds per preset (alternating)."""
    import torch  # noqa: PLC0415

    from network.bench.model import smooth_input  # noqa: PLC0415
    from network.config import get_config  # noqa: PLC0415
    from network.model import PolarInverseModel  # noqa: PLC0415

    maps, mask = smooth_input(size, 0.5)
    models, out = {}, {}
    for name in names:
        torch.manual_seed(0)
        m = models[name] = PolarInverseModel(get_config(name)).eval()
        state = m.state_dict()
        out[name] = {
            "parameters": sum(p.numel() for p in m.parameters()),
            "state_dict_bytes_float32": _bytes(state),
            "state_dict_bytes_bfloat16": _bytes(
                {k: v.to(torch.bfloat16) if v.is_floating_point() else v for k, v in state.items()}
            ),  # fmt: skip
            "encode_seconds_all": [],
            "decode_seconds_all": [],
        }
    with torch.inference_mode():
        for _ in range(repeat + 1):  # the first round warms up
            for name, m in models.items():
                t0 = time.perf_counter()
                feats = m.encode(maps, mask)
                t1 = time.perf_counter()
                m.decode_dense(feats, maps, mask, stride=1)
                t2 = time.perf_counter()
                out[name]["encode_seconds_all"].append(t1 - t0)
                out[name]["decode_seconds_all"].append(t2 - t1)
    for entry in out.values():
        for key in ("encode", "decode"):
            entry[f"{key}_seconds_all"] = entry[f"{key}_seconds_all"][1:]
            entry[f"{key}_seconds_median"] = statistics.median(entry[f"{key}_seconds_all"])
        entry["decoder_share"] = entry["decode_seconds_median"] / (
            entry["encode_seconds_median"] + entry["decode_seconds_median"]
        )
    return out


def bf16_weights(checkpoint: Path, capture: Path) -> dict:
    """The checkpoint's predictions with bfloat16-rounded weights against float32, inside the mask."""
    import numpy as np  # noqa: PLC0415
    import torch  # noqa: PLC0415

    from network.checkpoint import load_checkpoint  # noqa: PLC0415
    from network.infer import load_input, predict  # noqa: PLC0415
    from network.metrics import normal_angle_deg  # noqa: PLC0415

    model, ckpt = load_checkpoint(checkpoint)
    inp = load_input(capture)
    kw = {"inputs": ckpt["inputs"], "input_scale": ckpt["input_scale"], "radiance": inp.radiance}
    ref = predict(model, inp.maps, inp.mask, **kw)
    model.load_state_dict({k: v.to(torch.bfloat16) for k, v in ckpt["model"].items()})  # cast back on copy
    got = predict(model, inp.maps, inp.mask, **kw)
    m = inp.mask
    angle = normal_angle_deg(ref["normal"][m], got["normal"][m])
    result = {"checkpoint": str(checkpoint), "capture": str(capture), "masked_pixels": int(m.sum()),
              "normal_angle_deg_max": float(angle.max()), "normal_angle_deg_mean": float(angle.mean())}  # fmt: skip
    for key in ("albedo", "roughness", "metallic"):
        result[f"{key}_abs_max"] = float(np.abs(ref[key][m] - got[key][m]).max())
    return result


def main(argv: list[str] | None = None) -> int:
    """Run the measurement; prints the JSON."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--configs", nargs="+", default=["small", "medium"])
    parser.add_argument("--size", type=int, default=384)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--checkpoint", type=Path, default=ROOT / "models" / "small" / "model.pt")
    parser.add_argument("--capture", type=Path, default=ROOT / "examples" / "capture")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args(argv)
    import json  # noqa: PLC0415
    import os  # noqa: PLC0415

    import torch  # noqa: PLC0415

    result = {"threads": torch.get_num_threads(), "load_average_at_start": list(os.getloadavg()),
              "size": args.size, "presets": presets(args.configs, args.size, args.repeat)}  # fmt: skip
    if args.checkpoint.is_file():
        result["bf16_weights"] = bf16_weights(args.checkpoint, args.capture)
    result["load_average_at_end"] = list(os.getloadavg())
    text = json.dumps(result, indent=2)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
