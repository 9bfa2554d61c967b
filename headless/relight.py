"""Import predicted PBR maps into Blender as a Principled BSDF asset and relight it with Cycles.

    python headless/relight.py --maps DIR [--name NAME] --out DIR [--frames 8] [--size 160]
        [--samples 16] [--hdr FILE] [--device CPU|GPU] [--save-blend]

Reads DIR/<NAME>_normal/_albedo/_roughness/_metallic/_mask.exr (what headless/infer.py writes;
any names the add-on's "Import PBR maps" recognises), builds the camera-parented asset
(blender_addon.pbr_import), then renders OUT/point_NNNN.png: a point light orbiting the asset
(--frames frames) and OUT/env_NNNN.png: a procedural sky or --hdr environment map. With
--save-blend the scene (asset, orbit animation, environment) is saved as OUT/<NAME>.blend for
artists. Runs with the bpy wheel (`pip install bpy`) or inside Blender:
`blender -b -P headless/relight.py -- <args>`.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _argv(argv: list[str] | None) -> list[str] | None:
    if argv is None and "--" in sys.argv:  # blender -b -P relight.py -- <args>
        return sys.argv[sys.argv.index("--") + 1 :]
    return argv


def relight(args: argparse.Namespace) -> list[Path]:
    """Import, relight, render and optionally save; returns the written files."""
    import bpy  # noqa: PLC0415

    from blender_addon import pbr_import  # noqa: PLC0415
    from blender_addon import relight as brelight  # noqa: PLC0415

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    files = sorted(args.maps.glob(f"{args.name}_*.exr")) if args.name else [args.maps]
    if args.name and not files:
        raise FileNotFoundError(f"{args.maps}: no {args.name}_*.exr maps")
    obj = pbr_import.import_pbr_maps(bpy.context, files, distance=args.distance, name=args.name or None)
    scale = args.size / max(scene.render.resolution_x, scene.render.resolution_y)
    scene.render.resolution_x = max(round(scene.render.resolution_x * scale), 8)
    scene.render.resolution_y = max(round(scene.render.resolution_y * scale), 8)
    scene.render.film_transparent = False
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    if args.frames > 0:
        # Orbit in front of the asset (its +z faces the camera); power for a radiance of about
        # 0.5 on a 0.5 albedo facing the light: L = rho / pi * P / (4 pi d^2).
        radius, height = 0.6 * args.distance, 0.6 * args.distance
        power = 4.0 * math.pi**2 * (radius**2 + height**2) * args.exposure
        light = brelight.add_point_light_orbit(scene, obj, radius=radius, height=height, frames=args.frames,
                                               energy=power)  # fmt: skip
        written += brelight.render_relit(scene, out, device=args.device, samples=args.samples, prefix="point_")
        light.hide_render = True
        brelight.add_environment(scene, hdr_path=args.hdr, strength=args.env_strength)
        written += brelight.render_relit(scene, out, device=args.device, samples=args.samples,
                                         frames=[scene.frame_start], prefix="env_")  # fmt: skip
        light.hide_render = False
    if args.save_blend:
        path = out / f"{args.name or obj.name}.blend"
        tmp = path.with_name(path.stem + ".tmp.blend")
        bpy.ops.wm.save_as_mainfile(filepath=str(tmp), compress=True, copy=True)
        os.replace(tmp, path)
        written.append(path)
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="relight.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--maps", type=Path, required=True, help="folder with the predicted maps (or one file)")
    parser.add_argument("--name", default="", help="map name prefix NAME in NAME_normal.exr (default: all maps)")
    parser.add_argument("--out", type=Path, required=True, help="output folder for frames and the .blend")
    parser.add_argument("--frames", type=int, default=8, help="point-light orbit frames; 0 = no rendering")
    parser.add_argument("--size", type=int, default=160, help="longest side of the rendered frames (default 160)")
    parser.add_argument("--samples", type=int, default=16, help="Cycles samples per pixel (default 16)")
    parser.add_argument("--distance", type=float, default=1.0, help="asset plane distance from the camera, m")
    parser.add_argument("--exposure", type=float, default=1.0, help="point-light power scale (default 1)")
    parser.add_argument("--hdr", type=Path, default=None, help="environment map (.hdr/.exr); default procedural sky")
    parser.add_argument("--env-strength", type=float, default=0.3, help="environment strength (default 0.3)")
    parser.add_argument("--device", default="CPU", choices=["CPU", "GPU"], help="Cycles device (default CPU)")
    parser.add_argument("--save-blend", action="store_true", help="save OUT/<NAME>.blend")
    parser.add_argument("--quiet", action="store_true", help="print only errors")
    args = parser.parse_args(_argv(argv))
    if args.frames < 0 or args.size < 8 or args.samples < 1:
        parser.error("--frames >= 0, --size >= 8 and --samples >= 1 are required")
    try:
        import bpy  # noqa: F401, PLC0415
    except ImportError:
        print("error: bpy is not importable: `pip install bpy` (Python 3.11) or run inside Blender", file=sys.stderr)
        return 2
    try:
        written = relight(args)
    except (ValueError, OSError, RuntimeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not args.quiet:
        print(f"wrote {len(written)} files to {args.out.resolve()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
