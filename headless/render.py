"""Generate a synthetic dataset of polarized display captures.

Random objects in front of the polarized display are rendered with Mitsuba 3, passed through
the camera model and the decoder.

    python headless/render.py --split NAME [--out DIR] [--count N] [--resume]
    python headless/render.py --out DIR --count N [--resolution 384] [--seed S] [--spp 32]
        [--assets DIR] [--shapes SET] [--objects MIN-MAX] [--pbrdfs DIR] [--table-fraction F]
        [--texture-fraction F] [--asset-materials] [--variant auto] [--rig FILE] [--rig-jitter F]
        [--corpus-fraction F] [--resume]
        [--shard K/N] [--scene SPEC.json] [--via-blender] [--npz] [--quiet]

Each sample is DIR/samples/NNNNNN.exr (nine maps, mask, normal, albedo, roughness, metallic,
depth; optionally Stokes) plus a JSON sidecar (rig, pose, material, Disney parameters, seeds,
versions); DIR/manifest.json lists the completed samples. Every sample is a pure function of
--seed and its index: --shard K/N renders the indices i with i % N == K (run N processes, e.g.
a job array, into the same folder), --resume skips completed samples after a kill.

--split renders one of the project's fixed splits (train, val, test-procedural, test-meshes,
test-pbrdf, and the data engine's train-engine, val-engine, test-scenes; pbrdf/data/splits.py)
with its own seed, count, resolution, spp, shapes, objects per scene, material mix and asset
corpus; test splits keep the raw brackets so they are scored through the real-capture path. The manifest
and every sidecar record the split; training refuses test splits.

Shapes: each object is drawn from a pool of built-in shapes (--shapes SET: procedural, the
default; generated: sharp-edged, concave, thin and multi-part training shapes; train: both;
meshes: the unseen test meshes) plus, with --assets DIR, the asset files there. With --assets
and no --shapes the pool is the asset files alone (--shapes none says so explicitly).
--objects N or MIN-MAX puts that many objects in each scene (default 1), their bounding
spheres disjoint (an object without a free pose after 20 draws is left out). Materials:
analytic polarimetric ones (pplastic and rough conductors) with random parameters, or with
--pbrdfs DIR entries of that pBRDF table library; --table-fraction F draws each object's
material from the library with probability F and analytic otherwise (default 1 with --pbrdfs,
0 without). --texture-fraction F gives each drawn material seeded procedural textures with
probability F (base colour and roughness that vary, metal segments or worn paint, a mild normal
map, a mix of pBRDF tables; default 0: uniform materials; a --split's own fraction, which F
overrides for train and val splits, never for test splits); --asset-materials keeps the materials
of asset files that have them (glTF metallic-roughness, OBJ+MTL: one object per material, with
its textures) instead of drawing one. --corpus-fraction F draws each object from the real-mesh
training corpus (corpora/meshes: Debian's libcgal-demo and openscad-testing-data meshes, unpacked by
`make setup`; no test split uses them) with probability F. --rig-jitter F renders every scene through a rig
whose imperfections (cross-talk, ambient light, vignetting, QWP, extinction, display polarization) are
drawn within F times the documented residual ranges and decodes it with the nominal rig
(docs/rig_imperfections.md; a --split's own value, which F overrides for train and val splits).
--variant picks the Mitsuba variant: auto (default; cuda_ad_mono_polarized when
Dr.Jit has a CUDA backend, else llvm), llvm, cuda, scalar (scalar_spectral_polarized, slow) or
any *_polarized variant name; --split renders with llvm unless --variant is given. --scene
renders one given scene spec (e.g. exported by the Blender add-on) instead of random scenes
(--count defaults to 1). --npz also writes DIR/arrays/NNNNNN.npz (numpy only, read by the
add-on).

Two routes, same arguments, same files for the same seeds:
  - bpy-free (default): python headless/render.py ...
  - Blender: every scene is laid out in Blender (rig, objects, materials, lights) and exported
    back to a spec before rendering (blender_addon.build_spec.roundtrip_spec). Either
        blender -b --python-exit-code 1 -P headless/render.py -- --out DIR --count N ...
            (Blender 4.2+; the arguments follow "--"; Blender's Python needs mitsuba, scipy,
            trimesh, OpenEXR, tqdm: <blender python> -m pip install ...)
    or, with the bpy wheel (pip install bpy, Python 3.11):
        python headless/render.py --via-blender --out DIR --count N ...
    Inside the Blender binary the Blender route is always taken. An older Blender (or bpy) is
    refused with one line "error: render.py needs Blender 4.2 or later, this is X.Y.Z" and
    status 2. Inside the binary the exit status is the script's own, and an uncaught error is
    one "error: ..." line with status 1 (Blender alone would exit 0 after a Python error:
    --python-exit-code 1, before -P, also covers errors before this script runs).
One process renders a whole batch (start one process per shard) through
blender_addon.core.generate.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import flag_wording, in_blender_binary, refuse_old_blender, run_main, script_args  # noqa: E402

if __name__ == "__main__":
    refuse_old_blender("render.py")  # the Blender binary's route: an old Blender is refused before other imports

from pbrdf.data.splits import SPLITS, get_split  # noqa: E402


def _apply_split(args: argparse.Namespace) -> str | None:
    """Fill the arguments a ``--split`` fixes; returns the split name (None without --split)."""
    if args.split is None:
        return None
    split = get_split(args.split)
    if args.seed is not None and args.seed != split.seed:
        raise ValueError(f"--split {split.name} renders with seed {split.seed}; --seed cannot change it")
    if args.scene is not None or args.assets is not None:
        raise ValueError("--split draws its own scenes: it cannot be combined with --scene or --assets")
    if args.objects is not None or args.table_fraction is not None:
        raise ValueError(f"--split {split.name} fixes the objects and materials: drop --objects and --table-fraction")
    if args.texture_fraction is not None and split.role == "test":
        raise ValueError(f"--split {split.name} is a fixed test split: drop --texture-fraction")
    if split.pbrdfs and args.pbrdfs is None:
        raise ValueError(f"--split {split.name} needs --pbrdfs DIR (expanded tables; `make test-sets` makes them)")
    if not split.pbrdfs and args.pbrdfs is not None:
        raise ValueError(f"--split {split.name} uses analytic materials: drop --pbrdfs")
    if args.count is not None and not 1 <= args.count <= split.count:
        raise ValueError(f"--count must be in 1..{split.count} for --split {split.name}, got {args.count}")
    args.seed = split.seed
    args.count = split.count if args.count is None else args.count
    args.resolution = split.resolution if args.resolution is None else args.resolution
    args.spp = split.spp if args.spp is None else args.spp
    args.shapes = args.shapes or split.shapes
    if args.shapes != split.shapes:
        raise ValueError(f"--split {split.name} uses --shapes {split.shapes}")
    if args.pattern is not None and args.pattern != split.pattern:
        raise ValueError(f"--split {split.name} shows the {split.pattern!r} pattern; drop --pattern")
    args.pattern = split.pattern if split.pattern != "rgb_halves" else None
    args.keep_raw = args.keep_raw or split.keep_raw
    args.objects = f"{split.objects[0]}-{split.objects[1]}"
    args.table_fraction = split.table_fraction
    if args.texture_fraction is None:  # train and val splits take another fraction (a folder of its own)
        args.texture_fraction = split.texture_fraction
    args.asset_materials = args.asset_materials or split.asset_materials
    args.distance = split.distance
    if args.rig_jitter is not None and split.role == "test":
        raise ValueError(f"--split {split.name} is a fixed test split: drop --rig-jitter")
    args.rig_jitter = split.rig_jitter if args.rig_jitter is None else args.rig_jitter
    if args.corpus_fraction is not None:
        raise ValueError(f"--split {split.name} fixes its corpus fraction: drop --corpus-fraction")
    args.corpus_fraction = split.corpus_fraction
    args.corpus = split.corpus_folder()
    args.assets = split.asset_folder()
    args.variant = args.variant or "llvm"  # the variant the splits were made with, GPU or not
    args.out = args.out or Path("out/splits") / split.name
    return split.name


def _corpus(args: argparse.Namespace) -> Path | None:
    """The mesh corpus folder: the --split's, else the default one when --corpus-fraction asks for it."""
    if getattr(args, "corpus", None) is not None or not args.corpus_fraction:
        return getattr(args, "corpus", None)
    from pbrdf.data.splits import MESH_CORPUS_DIR  # noqa: PLC0415

    if not MESH_CORPUS_DIR.is_dir():
        raise ValueError(f"--corpus-fraction needs the mesh corpus in {MESH_CORPUS_DIR} (`make setup` unpacks it)")
    return MESH_CORPUS_DIR


#: The GenerateConfig fields that are flags here (its errors name them as ``field=value``).
GENERATE_FLAGS = ("count", "resolution", "seed", "spp", "shapes", "objects", "table_fraction", "variant", "assets",
                  "pbrdfs", "rig", "pattern", "scene", "shard", "texture_fraction", "asset_materials", "rig_jitter",
                  "corpus_fraction")  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="render.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, help="dataset folder (default with --split: out/splits/NAME)")
    parser.add_argument(
        "--split",
        choices=list(SPLITS),
        help="render a fixed split (pbrdf/data/splits.py): its seed, count, resolution, spp, shapes and raw "
        "brackets; --count renders only its first N scenes",
    )
    parser.add_argument("--count", type=int, help="total number of samples in the dataset (default 1 with --scene)")
    parser.add_argument("--resolution", type=int, help="sample size in pixels (default 384)")
    parser.add_argument("--seed", type=int, help="run seed (default 0)")
    parser.add_argument("--spp", type=int, help="samples per pixel per colour pass (default 32)")
    parser.add_argument(
        "--shapes",
        choices=["procedural", "generated", "train", "meshes", "none"],
        help="built-in shapes in the pool: procedural (default), generated, train (procedural + generated), "
        "meshes (unseen test meshes), none (with --assets; the default there)",
    )
    parser.add_argument(
        "--assets", type=Path, help="folder of GLB/GLTF/OBJ/PLY assets, added to the --shapes pool (default: none)"
    )
    parser.add_argument("--objects", help="objects per scene: N or MIN-MAX, inclusive (default 1)")
    parser.add_argument("--pbrdfs", type=Path, help="folder with materials.json and pBRDF tables (default: analytic)")
    parser.add_argument(
        "--table-fraction",
        type=float,
        help="probability that an object's material comes from --pbrdfs rather than analytic (default 1 with "
        "--pbrdfs, else 0; > 0 needs --pbrdfs)",
    )
    parser.add_argument(
        "--texture-fraction",
        type=float,
        help="probability that an object's drawn material gets seeded procedural textures (default 0: uniform)",
    )
    parser.add_argument(
        "--asset-materials",
        action="store_true",
        help="keep the materials of asset files that have them (glTF, OBJ+MTL): one object per material",
    )
    parser.add_argument(
        "--variant",
        help="Mitsuba variant: auto (default: cuda when Dr.Jit has CUDA, else llvm; llvm for --split), llvm, cuda, "
        "scalar, or a *_polarized variant name",
    )
    parser.add_argument("--rig", type=Path, help="rig JSON overriding the default rig (calibrated rigs)")
    parser.add_argument(
        "--rig-jitter",
        type=float,
        help="draw the rig's imperfections per scene within F times the documented residual ranges "
        "(docs/rig_imperfections.md), decode with the nominal rig (default 0, or the --split's; train and val only)",
    )
    parser.add_argument(
        "--corpus-fraction",
        type=float,
        help="probability that an object is a real mesh of the training corpus (corpora/meshes, `make setup`; "
        "default 0)",
    )
    parser.add_argument("--pattern", help="display pattern: rgb_halves (default), white, or an image file; "
                        "the scenes stay those of --seed")  # fmt: skip
    parser.add_argument("--scene", type=Path, help="render this scene spec JSON instead of random scenes")
    parser.add_argument("--via-blender", action="store_true", help="lay every scene out in Blender (bpy) first")
    parser.add_argument("--npz", action="store_true", help="also write DIR/arrays/NNNNNN.npz (numpy only)")
    parser.add_argument("--resume", action="store_true", help="continue a killed run: skip completed samples")
    parser.add_argument("--shard", default="0/1", help="K/N: render only indices i with i %% N == K (default 0/1)")
    parser.add_argument("--keep-stokes", action="store_true", help="also store the rendered Stokes images")
    parser.add_argument("--keep-raw", action="store_true", help="also store the raw HDR bracket (capture folder)")
    parser.add_argument("--no-noise", action="store_true", help="noise-free camera model")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("-v", "--verbose", action="store_true", help="log tracebacks of failed samples")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, 1 when samples failed, 2 on an error)."""
    args = build_parser().parse_args(script_args(sys.argv) if argv is None else argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING, format="%(levelname)s %(message)s")

    from blender_addon.core.generate import GenerateConfig, generate, parse_objects  # noqa: PLC0415
    from pbrdf.data.dataset import parse_shard  # noqa: PLC0415

    try:
        split = _apply_split(args)
        if args.out is None:
            raise ValueError("--out is required (unless --split is given)")
        if args.count is None and args.scene is None:
            raise ValueError("--count is required (unless --scene or --split is given)")
        spec_hook = None
        if args.via_blender or in_blender_binary():
            from blender_addon.compat import blender_refusal, running_blender  # noqa: PLC0415

            try:
                from blender_addon.build_spec import roundtrip_spec  # noqa: PLC0415 - imports bpy
            except ImportError as e:
                raise ValueError(
                    f"--via-blender needs bpy ({e}): run under 'blender -b -P headless/render.py -- ...' "
                    "or pip install bpy (Python 3.11)"
                ) from None
            problem = blender_refusal(running_blender())
            if problem:  # the bpy wheel's route (the binary's was refused at start-up)
                raise ValueError(f"render.py --via-blender {problem}")
            spec_hook = roundtrip_spec
        cfg = GenerateConfig(
            out=args.out,
            count=1 if args.count is None else args.count,
            resolution=384 if args.resolution is None else args.resolution,
            seed=0 if args.seed is None else args.seed,
            spp=32 if args.spp is None else args.spp,
            shapes=args.shapes,
            objects=parse_objects(args.objects) if args.objects is not None else (1, 1),
            table_fraction=args.table_fraction,
            texture_fraction=args.texture_fraction or 0.0,
            asset_materials=args.asset_materials,
            distance=getattr(args, "distance", None) or (0.5, 1.0),
            rig_jitter=args.rig_jitter or 0.0,
            corpus_fraction=args.corpus_fraction or 0.0,
            corpus=_corpus(args),
            variant=args.variant or "auto",
            split=split,
            assets=args.assets,
            pbrdfs=args.pbrdfs,
            rig=args.rig,
            pattern=args.pattern,
            resume=args.resume,
            shard=parse_shard(args.shard),
            keep_stokes=args.keep_stokes,
            keep_raw=args.keep_raw,
            noise=not args.no_noise,
            scene=args.scene,
            npz=args.npz,
        )
        report = generate(cfg, progress=not args.quiet, spec_hook=spec_hook)
    except (ValueError, OSError) as exc:
        print(f"error: {flag_wording(str(exc), GENERATE_FLAGS)}", file=sys.stderr)
        return 2
    print(report.summary())
    return 1 if report.failed else 0


if __name__ == "__main__":
    run_main(main)  # inside `blender -b -P` too: the exit status reaches the shell, any failure is one line
