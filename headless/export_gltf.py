"""Write predicted maps as one glTF 2.0 asset (.glb) that Blender, Unreal, Unity, three.js and Substance open.

    python headless/export_gltf.py --input (pred/ | map files...) --out asset.glb [--card] [--quiet]

Reads a prediction of ``headless/infer.py`` (``<name>_normal.exr``, ``_albedo``, ``_roughness``,
``_metallic``, ``_mask``, ``_depth`` and ``<name>_camera.json``; files are matched by name tokens
as the Blender import does, ``blender_addon/core/map_names.py``) and writes what
``infer.py --gltf`` writes (``pbrdf/data/gltf_asset.py``): the relief mesh (a flat card with
--card or without a depth map, at capture.json's distance or 0.75 m) with UVs, a base-colour
texture (sRGB albedo, the mask as alpha, cut at 0.5), a metallic-roughness texture (roughness
in G, metallic in B), a tangent-space normal map baked from the predicted normals against the
file's own vertex tangents, and the capture camera. Missing albedo, roughness or metallic maps
take the Principled BSDF's defaults (0.8, 0.5, 0). The add-on's "Export glTF" button runs this
script in the project's Python.

Bad input (no normal map, no ``<name>_camera.json``, maps that disagree) prints one line
"error: <message>" on stderr, exits with status 2 and writes nothing.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from headless._cli import held_warnings  # noqa: E402

#: What a missing map stands for (the Principled BSDF's defaults).
DEFAULTS = {"albedo": 0.8, "roughness": 0.5, "metallic": 0.0}


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="export_gltf.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--input", type=Path, nargs="+", required=True, help="prediction folder, or its map files")
    parser.add_argument("--out", type=Path, required=True, help="the .glb to write")
    parser.add_argument("--card", action="store_true", help="a flat card facing the camera, not the relief")
    parser.add_argument("--quiet", action="store_true", help="no progress output (the summary line still prints)")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 on an error)."""
    args = build_parser().parse_args(argv)
    summary: list[str] = []
    code = held_warnings(lambda: _export(args, summary))
    if not code:
        print(summary[0])
    return code


def _export(args: argparse.Namespace, summary: list[str]) -> int:
    import numpy as np  # noqa: PLC0415

    from blender_addon.core import map_io, map_names  # noqa: PLC0415
    from pbrdf.data.capture_meta import DEFAULT_DISTANCE_M  # noqa: PLC0415
    from pbrdf.data.gltf_asset import build_asset, write_asset  # noqa: PLC0415
    from pbrdf.data.predictions import CameraRecord  # noqa: PLC0415

    if args.out.suffix.lower() != ".glb":
        raise ValueError(f"{args.out}: --out must name a .glb file")
    files = map_names.match_map_files(args.input[0] if len(args.input) == 1 else args.input)
    camera_path = map_names.camera_file(files.files)
    if camera_path is None:
        raise FileNotFoundError(
            f"{files.files['normal'].parent}: no <name>_camera.json beside the maps (the asset needs their intrinsics)"
        )
    camera = CameraRecord.read(camera_path)
    maps = map_io.load_maps(files)
    for line in maps.warnings:
        warnings.warn(line, stacklevel=1)
    if maps.shape != (camera.height, camera.width):
        raise ValueError(f"{camera_path}: width, height: {camera.width} x {camera.height}, but the maps are "
                         f"{maps.shape[1]} x {maps.shape[0]}")  # fmt: skip
    inside = maps.valid
    pred = {"normal": np.where(inside[..., None], maps.normal, 0.0), "mask": inside[..., None].astype(np.float32)}
    for key, default in DEFAULTS.items():
        value = getattr(maps, key)
        value = np.full(maps.shape, default, np.float32) if value is None else value
        pred[key] = np.where(inside[..., None], value if value.ndim == 3 else value[..., None], 0.0)
    if maps.depth is not None and not args.card:
        pred["depth"] = np.where(inside, maps.depth, 0.0)[..., None]
    asset = build_asset(pred, camera.intrinsics, distance=camera.distance_m or DEFAULT_DISTANCE_M)
    path = write_asset(args.out, asset, name=args.out.stem)
    what = f"relief, {len(asset.mesh.positions)} vertices" if "depth" in pred else "card"
    summary.append(f"wrote {path.resolve()} ({what})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
