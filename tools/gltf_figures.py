"""Render glTF models with their own materials under the polarized display: a figure per model.

For docs/textured_assets.md: each model (every .gltf/.glb under --input, one folder per model)
is read with its materials (:func:`blender_addon.core.asset_materials.asset_parts`: one object
per material), scaled to a 30 cm diameter, centred 70 cm in front of the camera (its +z towards
the camera, +y up) and rendered polarized as a dataset sample is (three mono passes, the camera
model skipped). The figure shows what the camera sees (unpolarized RGB, tone-mapped; degree of
linear polarization) beside the ground truth of exactly what was rendered (albedo, roughness,
metallic, camera-space normal)::

    python tools/gltf_figures.py --input ../shared/assets/gltf-samples --out docs/figures/gltf

Timings per model are printed and written to ``--out/timings.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

if not __package__:  # run as a file: the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402


def model_scene(path: Path, *, diameter_m: float = 0.3, distance_m: float = 0.7):
    """The scene spec of one model with its own materials, posed in front of the camera."""
    from blender_addon.core import assets, scenegen  # noqa: PLC0415
    from blender_addon.core.asset_materials import asset_parts  # noqa: PLC0415
    from blender_addon.core.procedural import diameter  # noqa: PLC0415
    from blender_addon.core.spec import SceneSpec  # noqa: PLC0415

    mesh = assets.load_mesh(str(path))
    v = np.asarray(mesh.vertices, np.float64)
    centre = (v.min(axis=0) + v.max(axis=0)) / 2
    scale = diameter_m / diameter(mesh)
    m = np.eye(4)
    m[:3, :3] *= scale
    m[:3, 3] = -scale * centre + np.array([0.0, 0.0, -distance_m])
    to_world = tuple(map(tuple, m))
    parts = asset_parts(str(path))
    if parts is None:
        raise ValueError(f"{path}: no materials")
    objs, mats = [], []
    scenegen._add_parts(parts, np.random.default_rng(0), to_world, "object", objs, mats)
    return SceneSpec(objects=tuple(objs), materials=tuple(mats), seed=1, metadata={"notes": list(parts.notes)})


def _tone(rgb: np.ndarray) -> np.ndarray:
    """Linear RGB -> display: exposure at the 99th percentile, sRGB gamma."""
    peak = np.percentile(rgb, 99) if rgb.any() else 1.0
    x = np.clip(rgb / max(peak, 1e-8), 0, 1)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def figure(name: str, result, truth: dict, out: Path) -> Path:
    """The model's figure: unpol RGB, DoLP, truth albedo, roughness, metallic, normal."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    s = result.stokes  # (H, W, 3 channels, 4)
    s0 = s[..., 0]
    dolp = np.sqrt(s[..., 1] ** 2 + s[..., 2] ** 2).sum(-1) / np.maximum(s0.sum(-1), 1e-8)
    cover = (result.coverage >= 0.5) & (result.object_index >= 0)
    panels = [
        ("what the camera sees (S0)", _tone(s0), None),
        ("degree of linear polarization", np.where(cover, dolp, np.nan), (0, 1)),
        ("truth: albedo", _tone(truth["albedo"]) * cover[..., None], None),
        ("truth: roughness", np.where(cover, truth["roughness"], np.nan), (0, 1)),
        ("truth: metallic", np.where(cover, truth["metallic"], np.nan), (0, 1)),
        ("truth: normal", (0.5 + 0.5 * result.normal) * cover[..., None], None),
    ]
    fig, axes = plt.subplots(1, len(panels), figsize=(2.3 * len(panels), 2.6))
    for ax, (title, img, lim) in zip(axes, panels, strict=True):
        if img.ndim == 2:
            ax.imshow(img, vmin=lim[0], vmax=lim[1], cmap="viridis")
        else:
            ax.imshow(np.clip(img, 0, 1))
        ax.set_title(title, fontsize=8)
        ax.axis("off")
    fig.suptitle(name, fontsize=10)
    fig.tight_layout()
    path = out / f"{name}.png"
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    """Command line (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--input", type=Path, required=True, help="folder of model folders (.gltf/.glb)")
    parser.add_argument("--out", type=Path, required=True, help="figure folder")
    parser.add_argument("--resolution", type=int, default=256, help="render size in pixels (default 256)")
    parser.add_argument("--spp", type=int, default=32, help="samples per pixel per colour pass (default 32)")
    args = parser.parse_args(argv)

    from blender_addon.core.render import RenderSettings, ground_truth, render_stokes  # noqa: PLC0415

    args.out.mkdir(parents=True, exist_ok=True)
    timings = {}
    files = sorted(p for p in args.input.rglob("*") if p.suffix.lower() in (".gltf", ".glb"))
    for path in files:
        t0 = time.perf_counter()
        try:
            spec = model_scene(path)
            result = render_stokes(spec, RenderSettings(resolution=args.resolution, spp=args.spp, noise=False))
        except (OSError, ValueError) as e:
            print(f"{path.stem}: skipped: {e}", file=sys.stderr)
            continue
        seconds = time.perf_counter() - t0
        figure(path.stem, result, ground_truth(spec, result), args.out)
        timings[path.stem] = {"seconds": round(seconds, 2), "parts": len(spec.objects),
                              "kinds": sorted({m.kind for m in spec.materials}),
                              "textured": sum(m.textures is not None for m in spec.materials),
                              "notes": spec.metadata.get("notes", [])}  # fmt: skip
        print(f"{path.stem}: {seconds:.1f} s, {len(spec.objects)} parts")
    (args.out / "timings.json").write_text(json.dumps(timings, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
