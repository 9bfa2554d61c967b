"""Benchmarks with JSON output: run time against error, measured side by side in one run.

    python headless/bench.py decode [--height 2048 --width 2448] [--repeat 5] [--out FILE] [--quick]
    python headless/bench.py render [--resolution 384] [--ref-spp 1024] [--spp 4 8 16 32 64]
                                    [--scenes analytic table] [--table FILE] [--variant llvm|cuda]
                                    [--out FILE]
    python headless/bench.py pbrdf [--count 40] [--out FILE]
    python headless/bench.py network [--configs toy small] [--paper] [--strides 1 2 4] [--threads 2]
                                     [--device cpu|cuda] [--input CAPTURE] [--frame CAPTURE] [--out FILE]
    python headless/bench.py loader --input SPLIT [--sizes 192 384] [--workers 0 1 2] [--batch 8]
                                    [--step-batches 4 8] [--config small] [--device cpu|cuda] [--out FILE]

decode: a raw IMX250MYR HDR bracket decoded into the nine maps on the half and full grids, next
to polanalyser's demosaic + Stokes (network.bench.decode). render: time per dataset sample to
2 % map error for the default and two naive Mitsuba configurations, JIT compilation apart, on the
benchmark blob with an analytic material and with a pBRDF table (network.bench.render). pbrdf:
PCA error against components, validity-filter throughput, expansion speed
(network.bench.expansion). network: inference and training time and memory per model config,
and network.infer.predict on a capture with the shipped model: its time and the error of each
decoding stride against stride 1 (network.bench.model). With --frame (a full-frame capture, e.g.
`tools/make_example_capture.py --resolution 1224 --height 1024`): that capture's rows
(network.bench.fullframe): every stage of headless/infer.py timed once (full_frame.profile,
a Markdown table in .table), and predict at stride 1 and each --strides value side by side with
the error of each against stride 1 and whether it holds the tolerance (full_frame.strides),
and the relief depth by both preconditioners, side by side, with their difference (full_frame.depth),
and the maps without and with the test-time refinement side by side (full_frame.refine: infer.py
--no-refine against its default where a distance is known; the refinement's own seconds).
loader: training samples per second from EXR samples and from a pack (headless/pack.py) of
the first --count samples of SPLIT written at each size, per loader worker count, next to the
model's training step rate per batch size (network.bench.loader).

One timing rule everywhere (network.bench.timing): --warmup untimed calls, then --repeat timed
calls; every timed entry reports what it timed, its median (seconds_median) and all samples
(seconds_all). The JSON goes to stdout and, with --out, to FILE. --quick shrinks the sizes for
a smoke test.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pbrdf.io.strict_json import dumps_strict  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: The render benchmark's scenes (:func:`render_scenes`).
RENDER_SCENES = ("analytic", "table", "textured", "table_textured")
#: Seed material (:mod:`pbrdf.brdf.seeds`) tabulated for the table scene when no --table is given.
TABLE_SEED = "pom"
#: Seed material mixed with the table in the textured table scene (a dielectric, as ``pom``).
TEXTURED_TABLE_SEED = "peek"
#: Sizes of --quick (a smoke test), per benchmark.
QUICK = {
    "decode": {"height": 128, "width": 160, "repeat": 2},
    "render": {"resolution": 32, "ref_spp": 64, "spp": [4, 16]},  # naive rows on the analytic scene only
    "pbrdf": {"count": 4, "repeat": 1},
    "network": {"configs": ["toy"], "paper": False, "strides": [1, 2], "checkpoint": None, "frame": None},
    "loader": {
        "count": 2,
        "sizes": [64],
        "workers": [0, 1],
        "batch": 2,
        "batches": 2,
        "step_batches": [2],
        "config": "toy",
    },
}


def render_scenes(names: list[str], table: Path | None, folder: Path) -> dict[str, tuple]:
    """The render benchmark's scenes by name: ``(spec, description)``.

    ``analytic`` is :func:`blender_addon.core.scenegen.benchmark_scene`; ``table`` the same blob
    with a pBRDF table: ``table``, or the :data:`TABLE_SEED` seed material tabulated into
    ``folder``. ``textured``: the analytic blob with albedo and roughness textures;
    ``table_textured``: the table mixed per texel with :data:`TEXTURED_TABLE_SEED` and darkened by
    an albedo texture (textures written into ``folder``). Like for like: the textures vary what the
    plain rows hold constant, so the rows show what texturing costs.
    """
    import dataclasses  # noqa: PLC0415

    from blender_addon.core.scenegen import benchmark_scene  # noqa: PLC0415
    from blender_addon.core.spec import MaterialSpec  # noqa: PLC0415
    from pbrdf.brdf import seeds  # noqa: PLC0415
    from pbrdf.brdf import table as tables  # noqa: PLC0415

    spec = benchmark_scene()
    out: dict[str, tuple] = {}
    if "analytic" in names:
        out["analytic"] = (spec, "blob, pplastic albedo (0.6, 0.4, 0.2), roughness 0.3, 0.7 m")
    if "table" in names or "table_textured" in names:
        seed = next(m for m in seeds.SEED_MATERIALS if m.name == TABLE_SEED)
        if table is None:
            table = folder / f"{TABLE_SEED}.pbsdf"
            tables.save_table(table, seeds.seed_table(seed), for_mitsuba=True)
            what = f"seed material {TABLE_SEED!r} tabulated on the {seeds.DEFAULT_GRID} grid"
        else:
            what = str(table)
        albedo = (seed.albedo[3], seed.albedo[1], seed.albedo[0])  # 600, 500, 450 nm: about R, G, B
        name = spec.objects[0].material
        mat = MaterialSpec.measured(name, str(table), albedo, roughness=seed.roughness, metallic=0.0)
        out["table"] = (dataclasses.replace(spec, materials=(mat,)), f"blob, pBRDF table ({what}), 0.7 m")
    if "textured" in names or "table_textured" in names:
        from blender_addon.core.textures import MaterialTextures  # noqa: PLC0415

        albedo, rough, mask = _bench_textures(folder)
        plastic = spec.materials[0]
        tex = MaterialTextures(albedo=albedo, roughness=rough)
        out["textured"] = (
            dataclasses.replace(spec, materials=(dataclasses.replace(plastic, textures=tex),)),
            "blob, pplastic with 256 px albedo and roughness (0.2 / 0.4 stripes) textures, 0.7 m",
        )
        if "table" in out:
            other = folder / f"{TEXTURED_TABLE_SEED}.pbsdf"
            seed = next(m for m in seeds.SEED_MATERIALS if m.name == TEXTURED_TABLE_SEED)
            tables.save_table(other, seeds.seed_table(seed), for_mitsuba=True)
            tex = MaterialTextures(albedo=albedo, tables=(str(other),), weights=mask)
            own = out["table"][0].materials[0]
            out["table_textured"] = (dataclasses.replace(spec, materials=(dataclasses.replace(own, textures=tex),)),
                                     f"blob, the table and {TEXTURED_TABLE_SEED!r} mixed by a 256 px checker, "
                                     "darkened by an albedo texture, 0.7 m")  # fmt: skip
    return {k: v for k, v in out.items() if k in names}


def _bench_textures(folder: Path) -> tuple:
    """Albedo (smooth bands, sRGB), roughness (stripes 0.2 / 0.4) and a mask (a 4 x 4 checker) PNGs in ``folder``."""
    import numpy as np  # noqa: PLC0415
    from PIL import Image  # noqa: PLC0415

    from blender_addon.core.textures import TextureSpec  # noqa: PLC0415

    y, x = np.mgrid[:256, :256] / 256.0
    noise = 0.5 + 0.25 * np.sin(9 * x + 4 * np.sin(7 * y)) * np.cos(5 * y)
    images = {
        "albedo": np.stack([noise, 0.8 * noise, 0.5 * (1 - noise)], -1),
        "rough": np.repeat((0.2 + 0.2 * (np.sin(40 * x) > 0))[..., None], 3, -1),
        "mask": np.repeat(((np.floor(4 * x) + np.floor(4 * y)) % 2)[..., None], 3, -1),
    }
    for name, img in images.items():
        Image.fromarray((np.clip(img, 0, 1) * 255).astype(np.uint8)).save(folder / f"{name}.png")
    return (TextureSpec(str(folder / "albedo.png"), colorspace="srgb"),
            TextureSpec(str(folder / "rough.png"), channels=(1,), factor=(1.0,)),
            TextureSpec(str(folder / "mask.png"), channels=(2,), factor=(1.0,)))  # fmt: skip


def _default_checkpoint() -> Path | None:
    """The shipped model when present (for ``network``'s predict entry)."""
    path = ROOT / "models" / "small" / "model.pt"
    return path if path.is_file() else None


def _common(p: argparse.ArgumentParser, *, repeat: int, warmup: int = 1) -> None:
    """The flags every benchmark takes."""
    p.add_argument("--repeat", type=int, default=repeat, help=f"timed calls per entry; the median is reported "
                   f"(default {repeat})")  # fmt: skip
    p.add_argument("--warmup", type=int, default=warmup, help=f"untimed calls before them (default {warmup})")
    p.add_argument("--seed", type=int, default=0, help="seed (noise, scene or model initialisation; default 0)")
    p.add_argument("--out", type=Path, help="also write the JSON here")
    p.add_argument("--quick", action="store_true", help="small sizes for a smoke test (overrides the size flags)")
    p.add_argument("--quiet", action="store_true", help="no progress output (the JSON still prints)")


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="bench.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="what", required=True, metavar="{decode,render,pbrdf,network,loader}")

    def add(name: str, summary: str, module: str) -> argparse.ArgumentParser:
        # help= is %-formatted by argparse, description= is not
        description = f"{summary[0].upper()}{summary[1:]} ({module}).".replace("%%", "%")
        return sub.add_parser(name, help=summary, description=description)

    p = add("decode", "raw HDR bracket -> nine maps, against polanalyser", "network.bench.decode")
    p.add_argument("--height", type=int, default=2048, help="raw height in pixels (default 2048)")
    p.add_argument("--width", type=int, default=2448, help="raw width in pixels (default 2448)")
    _common(p, repeat=5)
    r = add("render", "time per sample to 2 %% map error, default vs naive configurations", "network.bench.render")
    r.add_argument("--resolution", type=int, default=384, help="sample size (default 384)")
    r.add_argument("--ref-spp", type=int, default=1024, help="reference samples per pixel (default 1024)")
    r.add_argument("--spp", type=int, nargs="+", default=[4, 8, 16, 32, 64], help="spp values to time")
    r.add_argument("--scenes", nargs="+", choices=list(RENDER_SCENES), default=list(RENDER_SCENES),
                   help="scenes to render (default: all)")  # fmt: skip
    r.add_argument("--table", type=Path, help=f"pBRDF tensor file of the table scene (default: the {TABLE_SEED!r} "
                   "seed material tabulated on the seeds' grid)")  # fmt: skip
    r.add_argument("--variant", default="llvm", help="Mitsuba variant or alias: llvm (default), cuda, auto "
                   "(cuda when Dr.Jit has a CUDA backend), or a *_mono_polarized name")  # fmt: skip
    _common(r, repeat=1)
    q = add("pbrdf", "PCA error vs components, validity-filter throughput, expansion speed", "network.bench.expansion")
    q.add_argument("--count", type=int, default=40, help="tables generated to time the expansion (default 40)")
    _common(q, repeat=3)
    nb = add("network", "time and memory per model config; stride error of the shipped model", "network.bench.model")
    nb.add_argument("--configs", nargs="+", default=["toy", "small"], choices=["toy", "small", "medium", "paper"])
    nb.add_argument("--paper", action="store_true", help="also run the paper config (minutes on a CPU)")
    nb.add_argument("--size", type=int, help="input size (default: the config's)")
    nb.add_argument("--mask-fraction", type=float, default=0.5, help="image fraction inside the mask (default 0.5)")
    nb.add_argument("--strides", type=int, nargs="+", default=[1, 2, 4], help="decode strides (default 1 2 4)")
    nb.add_argument("--threads", type=int, help="torch CPU threads (default: torch's)")
    nb.add_argument("--device", default="cpu", help="cpu (default) or cuda[:N]")
    nb.add_argument("--bf16", action="store_true", help="CUDA only: inference under bf16 autocast")
    nb.add_argument("--no-reference", dest="reference", action="store_false", help="skip the reference dense decoder")
    nb.add_argument("--paper-reference", action="store_true", help="also time paper's reference decoder (slow)")
    nb.add_argument("--skip-dense", action="store_true", help="skip inference except for toy")
    nb.add_argument("--no-train", dest="train", action="store_false", help="skip the training forward and step")
    nb.add_argument("--checkpoint", type=Path, default=_default_checkpoint(), help="trained model for predict()")
    nb.add_argument("--input", type=Path, metavar="CAPTURE",
                    help="capture folder or sample for predict() (default examples/capture)")  # fmt: skip
    nb.add_argument("--frame", type=Path, metavar="CAPTURE",
                    help="a full-frame capture: every stage of infer.py timed; its strides vs stride 1")  # fmt: skip
    _common(nb, repeat=1)
    lb = add("loader", "samples per second from EXR samples and from a pack, next to the model's step rate",
             "network.bench.loader")  # fmt: skip
    lb.add_argument("--input", type=Path, required=True, metavar="SPLIT", help="a rendered split (read only)")
    lb.add_argument("--count", type=int, default=16, help="samples of SPLIT copied and packed per size (default 16)")
    lb.add_argument("--sizes", type=int, nargs="+", default=[192, 384], help="sample sizes (default 192 384)")
    lb.add_argument("--workers", type=int, nargs="+", default=[0, 1, 2], help="loader workers (default 0 1 2)")
    lb.add_argument("--batch", type=int, default=8, help="samples per loader batch (default 8)")
    lb.add_argument("--batches", type=int, default=4, help="batches per timed block (default 4, at least 2 per worker)")
    lb.add_argument("--step-batches", type=int, nargs="*", default=[4, 8], help="model step batch sizes (default 4 8)")
    lb.add_argument("--config", default="small", help="model preset of the step rows (default small)")
    lb.add_argument("--device", default="cpu", help="cpu (default) or cuda[:N] for the step rows (bf16 on CUDA)")
    lb.add_argument("--threads", type=int, help="torch CPU threads (default: torch's)")
    lb.add_argument("--work", type=Path, help="folder for the copies and packs (default: a temporary folder)")
    _common(lb, repeat=3)
    return parser


def _run(args: argparse.Namespace, parser: argparse.ArgumentParser) -> dict:
    """Validate the arguments of one benchmark and run it."""
    if args.quick:
        for key, value in QUICK[args.what].items():
            setattr(args, key, value)
    if args.repeat < 1 or args.warmup < 0:
        parser.error("--repeat must be >= 1 and --warmup >= 0")
    common = {"repeat": args.repeat, "warmup": args.warmup, "seed": args.seed}
    if args.what == "decode":
        if args.height % 4 or args.width % 4 or min(args.height, args.width) < 32:
            parser.error("--height and --width must be multiples of 4 and at least 32")
        from network.bench import decode  # noqa: PLC0415

        return decode.run(height=args.height, width=args.width, **common)
    if args.what == "render":
        if sorted(args.spp) != list(args.spp) or min(args.spp) < 1 or args.ref_spp < max(args.spp):
            parser.error("--spp must be ascending and >= 1, and --ref-spp at least the largest")
        from blender_addon.core import render as renderer  # noqa: PLC0415
        from network.bench import render  # noqa: PLC0415

        with tempfile.TemporaryDirectory() as tmp:
            scenes = render_scenes(args.scenes, args.table, Path(tmp))
            return render.run(
                renderer, scenes, resolution=args.resolution, ref_spp=args.ref_spp, spp=tuple(args.spp),
                naive=["analytic"] if args.quick else ["analytic", "table"], variant=args.variant, **common,
            )  # fmt: skip
    if args.what == "pbrdf":
        from network.bench import expansion  # noqa: PLC0415

        return expansion.run(count=args.count, **common)
    if args.what == "loader":
        from network.bench import loader  # noqa: PLC0415

        return loader.run(
            source=args.input, count=args.count, sizes=tuple(args.sizes), workers=tuple(args.workers), batch=args.batch,
            batches=args.batches, step_batches=tuple(args.step_batches), config=args.config, device=args.device,
            threads=args.threads, work=args.work, repeat=args.repeat, step_repeat=max(1, args.repeat - 1),
            seed=args.seed,
        )  # fmt: skip
    if min(args.strides) < 1 or not 0 < args.mask_fraction <= 1:
        parser.error("--strides must be >= 1 and --mask-fraction in (0, 1]")
    configs = tuple(dict.fromkeys(args.configs + (["paper"] if args.paper else [])))
    if args.frame is not None:
        return {**_network(args, configs, common), "full_frame": _full_frame(args)}
    return _network(args, configs, common)


def _full_frame(args: argparse.Namespace) -> dict:
    """``network --frame``: the capture's stage profile, its strides against stride 1, its depth routes, refinement."""
    from network.bench import fullframe  # noqa: PLC0415

    if args.checkpoint is None or not args.checkpoint.is_file():
        raise ValueError(f"--frame needs a trained model; --checkpoint {args.checkpoint} is not a file")
    strides = tuple(s for s in args.strides if s != 1)
    return {"profile": fullframe.profile(args.frame, args.checkpoint),
            "strides": fullframe.stride_rows(args.frame, args.checkpoint, strides, repeat=args.repeat,
                                                warmup=args.warmup),
            "depth": fullframe.depth_rows(args.frame, args.checkpoint, repeat=max(3, args.repeat)),
            "refine": fullframe.refine_rows(args.frame, args.checkpoint, repeat=max(3, args.repeat),
                                            warmup=args.warmup)}  # fmt: skip


def _network(args: argparse.Namespace, configs: tuple, common: dict) -> dict:
    from network.bench import model  # noqa: PLC0415

    return model.run(
        configs=configs, size=args.size, mask_fraction=args.mask_fraction, strides=tuple(args.strides),
        threads=args.threads, device=args.device, bf16=args.bf16, reference=args.reference,
        paper_reference=args.paper_reference, skip_dense=args.skip_dense, train=args.train,
        checkpoint=args.checkpoint, capture=args.input or ROOT / "examples" / "capture", **common,
    )  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on an error)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        result = _run(args, parser)
    except (ValueError, OSError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    text = dumps_strict(result)
    print(text)
    if args.out:
        from pbrdf.io.atomic import atomic_write_text  # noqa: PLC0415

        args.out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out, text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
