"""`make demo`: the whole pipeline on built-in defaults, with an HTML report at the end.

    python headless/demo.py [--out out/demo] [--scenes 6] [--resolution 128] [--checkpoint model.pt] [--quiet]

Expands pBRDFs from the built-in seed set, builds random Objaverse-like procedural scenes,
renders polarized captures with Mitsuba 3 through the camera model (raw HDR brackets with
noise), decodes them, runs the shipped model (models/small/model.pt), evaluates against the
ground truth and the classical photometric-stereo baseline, imports the predictions into
Blender (bpy wheel) as Principled BSDF assets and relights them with Cycles under a rotating
point light and an environment map (network.demo.pipeline).

Writes to --out: pbrdfs/ (tables, figures), data/ (samples with raw capture folders),
predictions/ (EXR + PNG per scene), relit/ (frames, .blend), figures/, metrics.json,
metrics.md, timings.json and report.html, then prints a summary. A second run reuses finished
renders.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="demo.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder (default out/demo)")
    parser.add_argument("--scenes", type=int, default=6, help="scenes to render (default 6)")
    parser.add_argument("--measured-scenes", type=int, default=2,
                        help="of which with expanded pBRDF tables (default 2)")  # fmt: skip
    parser.add_argument("--resolution", type=int, default=128, help="map size in pixels (default 128)")
    parser.add_argument("--spp", type=int, default=16, help="samples per pixel per colour pass (default 16)")
    parser.add_argument("--tables", type=int, default=6, help="expanded pBRDF tables (default 6)")
    parser.add_argument("--checkpoint", type=Path, default=None, help="model.pt (default: the shipped model)")
    parser.add_argument("--relight-frames", type=int, default=6, help="point-light orbit frames (default 6)")
    parser.add_argument("--relight-size", type=int, default=128, help="relit frame size (default 128, the maps')")
    parser.add_argument("--relight-samples", type=int, default=4, help="Cycles samples (default 4)")
    parser.add_argument("--relight-denoise", action=argparse.BooleanOptionalAction, default=True,
                        help="Cycles' denoiser on the relit frames (default: %(default)s)")  # fmt: skip
    parser.add_argument("--no-blender", action="store_true", help="skip the Blender import and relighting")
    parser.add_argument("--seed", type=int, default=0, help="seed of everything (default 0)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars (the summary still prints)")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on an error)."""
    args = build_parser().parse_args(argv)
    from blender_addon.core.generate import GenerateConfig, generate  # noqa: PLC0415
    from network.demo import DemoConfig, run_demo  # noqa: PLC0415

    def render_dataset(*, progress: bool, **fields):  # raw brackets kept: the demo decodes them as captures
        return generate(GenerateConfig(keep_raw=True, resume=True, **fields), progress=progress)

    t0 = time.perf_counter()
    try:
        cfg = DemoConfig(
            out=args.out, scenes=args.scenes, measured_scenes=min(args.measured_scenes, args.scenes),
            resolution=args.resolution, spp=args.spp, tables=args.tables, checkpoint=args.checkpoint,
            relight_frames=args.relight_frames, relight_size=args.relight_size,
            relight_samples=args.relight_samples, relight_denoise=args.relight_denoise, seed=args.seed,
            blender=not args.no_blender,
            progress=not args.quiet,
        )  # fmt: skip
        summary = run_demo(cfg, render_dataset)
    except (ValueError, OSError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    mean = summary["mean"]
    ours, base = mean["ours"], mean["baseline"]
    print()
    print(f"demo finished in {time.perf_counter() - t0:.0f} s: {len(summary['scenes'])} scenes")
    print(f"  normal MAE   ours {ours['normal_mae']:6.2f} deg   baseline {base['normal_mae']:6.2f} deg")
    print(f"  albedo si-PSNR ours {ours['albedo_si_psnr']:5.2f} dB  baseline {base['albedo_si_psnr']:5.2f} dB")
    print(f"  roughness RMSE {ours['roughness_rmse']:.3f}   metallic RMSE {ours['metallic_rmse']:.3f}")
    print("  time per stage: " + ", ".join(f"{k} {v:.0f}s" for k, v in summary["timings_s"].items()))
    print(f"report: {(args.out / 'report.html').resolve()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
