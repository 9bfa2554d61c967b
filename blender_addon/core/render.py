"""Polarized rendering of a scene spec with Mitsuba 3, and the synthetic capture built from it.

:func:`render_stokes` renders the Stokes images per colour channel (one ``*_mono_polarized``
pass per channel, only the object's screen-space crop) plus ground-truth AOVs.
:func:`synthesize_sample` then sends the Stokes images through the foundation's camera model
(QWP, micro-polarizers, mosaic, noise, 12-bit HDR brackets) and decoder, exactly as a real
capture, and assembles a dataset sample (:mod:`pbrdf.dataset` format) with the ground truth.

Grids: Stokes and AOVs are rendered at the sample resolution R (one rendered pixel per 2x2
raw block); the raw mosaic is 2R x 2R (the Stokes value is held constant over each block) and
the decoder's ``"half"`` grid brings the nine maps back to R x R, pixel-aligned with the ground
truth.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from pbrdf import camera as pcamera
from pbrdf import decode as pdecode

from . import mitsuba_scene as ms

if TYPE_CHECKING:
    from .spec import SceneSpec

__all__ = [
    "RenderSettings",
    "RenderResult",
    "choose_variant",
    "render_window",
    "render_stokes",
    "synthesize_sample",
    "ground_truth",
    "PreviewSettings",
    "PreviewResult",
    "choose_rgb_variant",
    "render_preview",
]

log = logging.getLogger(__name__)

_VARIANT_CACHE: dict[str, str] = {}


@dataclass(frozen=True)
class RenderSettings:
    """How to render one sample.

    Attributes:
        resolution: output size R (the decoded maps are R x R; the raw mosaic 2R x 2R).
        spp: samples per pixel per colour pass.
        max_depth: path length limit (3: camera -> object -> object -> display, one
            interreflection; 2 would be direct light only).
        crop: render only the objects' screen-space bounding box (True) or the full sensor at
            the same sampling (benchmarks).
        margin: border around the bounding box, as a fraction of its size.
        integrator: ``"volpath"`` (default) or ``"path"`` (benchmarks only: it cannot see the
            display through the polarizer sheet with next-event estimation).
        sampler: Mitsuba sampler. ``multijitter`` (stratified, default) reaches 3.4 % relative
            RMSE at 16 spp where ``independent`` needs about 150 spp (headless/bench.py render).
        variant: Mitsuba variant, or None to choose (:func:`choose_variant`).
        noise: simulate sensor noise.
    """

    resolution: int = 384
    spp: int = 32
    max_depth: int = 3
    crop: bool = True
    margin: float = 0.06
    integrator: str = "volpath"
    sampler: str = "multijitter"
    variant: str | None = None
    noise: bool = True

    def __post_init__(self) -> None:
        if self.resolution < 8 or self.resolution % 2:
            raise ValueError(f"resolution must be even and >= 8, got {self.resolution}")
        if self.spp < 1:
            raise ValueError(f"spp must be >= 1, got {self.spp}")
        if self.integrator not in ("volpath", "path"):
            raise ValueError(f"integrator must be 'volpath' or 'path', got {self.integrator!r}")


@dataclass
class RenderResult:
    """Rendered Stokes images and AOVs on the crop window (H, W).

    Attributes:
        stokes: ``(H, W, 3, 4)`` float32 Stokes vectors per colour channel, camera frame.
        normal: ``(H, W, 3)`` unit shading normals in the camera frame (OpenGL), 0 on background.
        depth: ``(H, W)`` z-distance in metres along the camera's -z axis, 0 on background.
        coverage: ``(H, W)`` fraction of samples that hit an object.
        object_index: ``(H, W)`` int, index into ``spec.objects``, -1 on background.
        window: the crop window rendered.
        variant: Mitsuba variant used.
        seconds: wall time per pass.
    """

    stokes: NDArray[np.float32]
    normal: NDArray[np.float32]
    depth: NDArray[np.float32]
    coverage: NDArray[np.float32]
    object_index: NDArray[np.int32]
    window: ms.CropWindow
    variant: str
    seconds: dict = field(default_factory=dict)

    @property
    def mask(self) -> NDArray[np.bool_]:
        """Pixels at least half covered by an object."""
        return self.coverage >= 0.5


def choose_variant(preferred: str = "llvm_ad_mono_polarized") -> str:
    """Pick the Mitsuba variant: the LLVM mono-polarized one when Dr.Jit's LLVM backend works.

    LLVM older than 16 is rejected (LLVM 15 aborts on Mitsuba's polarized kernels; ``make
    setup`` installs libllvm19). Without it, falls back to ``scalar_spectral_polarized`` with a
    warning (much slower; the display pattern must be the built-in one there).
    """
    if preferred in _VARIANT_CACHE:
        return _VARIANT_CACHE[preferred]
    import mitsuba as mi  # noqa: PLC0415

    variant = preferred
    if preferred.startswith("llvm"):
        if not _llvm_ok():
            warnings.warn(
                "Dr.Jit's LLVM backend is inactive or older than LLVM 16 (install Debian's libllvm19, "
                "or run `make setup`); falling back to the slow scalar_spectral_polarized variant",
                RuntimeWarning,
                stacklevel=2,
            )
            variant = "scalar_spectral_polarized"
    if variant not in mi.variants():
        raise RuntimeError(f"Mitsuba variant {variant!r} is not available; have {mi.variants()}")
    _VARIANT_CACHE[preferred] = variant
    return variant


def _llvm_ok() -> bool:
    """Dr.Jit's LLVM backend works and is LLVM >= 16 (older versions abort on polarized kernels)."""
    import drjit as dr  # noqa: PLC0415

    return bool(dr.has_backend(dr.JitBackend.LLVM)) and tuple(dr.detail.llvm_version()) >= (16, 0, 0)


def choose_rgb_variant() -> str:
    """``llvm_ad_rgb`` when the LLVM backend works (:func:`choose_variant`'s test), else ``scalar_rgb``."""
    import mitsuba as mi  # noqa: PLC0415

    for variant in ("llvm_ad_rgb", "scalar_rgb"):
        if variant in mi.variants() and (not variant.startswith("llvm") or _llvm_ok()):
            return variant
    raise RuntimeError(f"no RGB Mitsuba variant is available; have {mi.variants()}")


def _set_variant(variant: str):
    import mitsuba as mi  # noqa: PLC0415

    if mi.variant() != variant:
        mi.set_variant(variant)
    mi.set_log_level(mi.LogLevel.Error)
    return mi


def _world_meshes(spec: SceneSpec) -> list[tuple[NDArray, NDArray, NDArray]]:
    """(vertices, faces, vertex normals) of every object, in world coordinates."""
    from . import assets  # noqa: PLC0415

    out = []
    for obj in spec.objects:
        mesh = assets.load_mesh(obj.mesh)
        m = np.asarray(obj.to_world, dtype=np.float64)
        v = np.asarray(mesh.vertices) @ m[:3, :3].T + m[:3, 3]
        n = np.asarray(mesh.vertex_normals) @ np.linalg.inv(m[:3, :3])  # inverse-transpose, row vectors
        n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
        out.append((v, np.asarray(mesh.faces), n))
    return out


def render_window(spec: SceneSpec, settings: RenderSettings, meshes: list | None = None) -> ms.CropWindow:
    """The crop window around the objects, or the whole sensor at the same sampling.

    With ``settings.crop`` False the object covers the same pixels as in the crop, which sits at
    the crop window's ``offset`` inside the full film.
    """
    cam = spec.rig.camera
    meshes = _world_meshes(spec) if meshes is None else meshes
    uv = np.concatenate([cam.project(v)[0] for v, _, _ in meshes])
    window = ms.crop_window(cam, uv, settings.resolution, margin=settings.margin)
    if settings.crop:
        return window
    return ms.CropWindow(window.binning, window.film_size, (0, 0), window.film_size)


def render_stokes(spec: SceneSpec, settings: RenderSettings = RenderSettings()) -> RenderResult:
    """Render the Stokes images (per colour channel) and ground-truth AOVs of a scene spec.

    Args:
        spec: validated scene spec (rig, objects, materials).
        settings: resolution, samples, cropping, variant.

    Returns:
        :class:`RenderResult` on the crop window.
    """
    variant = settings.variant or choose_variant()
    mi = _set_variant(variant)
    if "spectral" in variant:  # the fallback without LLVM, and cross-checks
        from .spectral import render_stokes_spectral  # noqa: PLC0415

        return render_stokes_spectral(spec, settings, variant=variant)
    rig = spec.rig
    cam = rig.camera
    meshes = _world_meshes(spec)
    window = render_window(spec, settings, meshes)
    materials = {m.name: m for m in spec.materials}
    names = [f"object_{i}" for i in range(len(spec.objects))]

    def build(channel: int):
        objs = {
            name: ms.mesh_object(name, v, f, n, ms.bsdf_dict(materials[obj.material], channel))
            for name, obj, (v, f, n) in zip(names, spec.objects, meshes, strict=True)
        }
        return mi.load_dict(
            ms.scene_dict(
                rig.display, cam, window, objs, channel,
                spp=settings.spp, max_depth=settings.max_depth, integrator=settings.integrator,
                sampler=settings.sampler,
            )
        )  # fmt: skip

    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    scene = build(0)
    params = mi.traverse(scene)
    seconds["load"] = time.perf_counter() - t0
    w, h = window.size
    stokes = np.zeros((h, w, 3, 4), dtype=np.float32)
    aovs: dict[str, NDArray] = {}
    for c in range(3):
        t0 = time.perf_counter()
        if c > 0:
            updates = {}
            for name, obj in zip(names, spec.objects, strict=True):
                u = ms.channel_updates(name, materials[obj.material], c)
                if u is None:
                    updates = None
                    break
                updates.update(u)
            if updates is None:
                scene = build(c)
                params = mi.traverse(scene)
            else:
                disp = ms.display_updates(rig.display, c, params)
                if disp is None:
                    scene = build(c)
                    params = mi.traverse(scene)
                else:
                    for k, v in {**disp, **updates}.items():
                        params[k] = v
                    params.update()
        img = np.asarray(mi.render(scene, seed=(int(spec.seed) * 3 + c) % 2**32, spp=settings.spp))
        # Mono layout: [Y, S0 x3, S1 x3, S2 x3, S3 x3, AOVs...].
        stokes[:, :, c, :] = img[:, :, [1, 4, 7, 10]]
        if c == 0:  # AOVs from the first pass, with that scene's shape ids
            aovs = aov_result(img[:, :, 13:], scene, spec, names)
        seconds[f"pass_{'RGB'[c]}"] = time.perf_counter() - t0
    return RenderResult(stokes=stokes, window=window, variant=variant, seconds=seconds, **aovs)


def aov_result(aov: NDArray, scene, spec: SceneSpec, names: list[str]) -> dict[str, NDArray]:
    """Coverage, camera-frame normals, depth and object index from the AOV block of a render.

    Args:
        aov: ``(H, W, 11)`` channels after the Stokes block: integrator RGBA, ``nn.XYZ``
            (shading normal), ``pp.XYZ`` (position), ``si.I`` (shape index), each averaged over
            the pixel's samples (so divided by the coverage here).
        scene: the Mitsuba scene that produced them (for the shape ids).
        spec: the scene spec (camera pose).
        names: Mitsuba shape names of ``spec.objects`` in order.
    """
    import drjit as dr  # noqa: PLC0415
    import mitsuba as mi  # noqa: PLC0415

    coverage = aov[..., 3]
    safe = np.where(coverage > 0, coverage, 1.0)[..., None]
    n_world = aov[..., 4:7] / safe
    p_world = aov[..., 7:10] / safe
    shape_index = aov[..., 10] / safe[..., 0]
    w2c = np.asarray(spec.rig.camera.world_to_camera(), dtype=np.float64)
    normal = n_world @ w2c[:3, :3].T
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)
    p_cam = p_world @ w2c[:3, :3].T + w2c[:3, 3]
    mask = coverage >= 0.5
    normal[~mask] = 0.0
    depth = np.where(mask, -p_cam[..., 2], 0.0)
    # The shape-index AOV holds Dr.Jit's registry id of the hit shape in JIT variants (global to
    # the process); in scalar variants it is 1 + the shape's position in scene.shapes()
    # (measured with mitsuba 3.9.1; both covered by tests).
    if mi.variant().startswith("scalar"):
        registry = np.arange(1, len(scene.shapes()) + 1)
    else:
        registry = np.asarray(dr.reinterpret_array(mi.UInt32, scene.shapes_dr())).reshape(-1)
    shape_names = [s.id() for s in scene.shapes()]
    index = np.full(coverage.shape, -1, dtype=np.int32)
    rounded = np.rint(shape_index).astype(np.int64)
    for i, name in enumerate(names):
        if name in shape_names:
            index[mask & (rounded == int(registry[shape_names.index(name)]))] = i
    return {
        "normal": normal.astype(np.float32),
        "depth": depth.astype(np.float32),
        "coverage": coverage.astype(np.float32),
        "object_index": index,
    }


def ground_truth(spec: SceneSpec, result: RenderResult) -> dict[str, NDArray]:
    """Material maps from the per-object Disney parameters: albedo (H,W,3), roughness, metallic."""
    materials = {m.name: m for m in spec.materials}
    h, w = result.object_index.shape
    albedo = np.zeros((h, w, 3), np.float32)
    rough = np.zeros((h, w), np.float32)
    metal = np.zeros((h, w), np.float32)
    for i, obj in enumerate(spec.objects):
        sel = result.object_index == i
        m = materials[obj.material]
        albedo[sel] = m.albedo
        rough[sel] = m.roughness
        metal[sel] = m.metallic
    return {"albedo": albedo, "roughness": rough, "metallic": metal}


def synthesize_sample(
    spec: SceneSpec,
    result: RenderResult,
    *,
    rng: np.random.Generator,
    noise: bool = True,
    keep_stokes: bool = False,
    keep_raw: bool = False,
) -> tuple[dict[str, NDArray], dict]:
    """Camera model + decode on rendered Stokes images -> dataset sample and metadata.

    Returns:
        ``(sample, metadata)`` in :mod:`pbrdf.dataset` format: ``maps`` (H,W,9), ``mask``,
        ``normal``, ``albedo``, ``roughness``, ``metallic``, ``depth`` (+ ``stokes``, ``raw``).
    """
    model = spec.rig.camera.model
    t0 = time.perf_counter()
    # Hold each rendered Stokes vector over its 2x2 raw block.
    up = np.repeat(np.repeat(result.stokes, 2, axis=0), 2, axis=1)
    raws = pcamera.simulate_capture(up, model, rng=rng, noise=noise)
    dec = pdecode.decode(raws, model, grid="half")
    t_camera = time.perf_counter() - t0
    mask = result.mask & dec.mask
    gt = ground_truth(spec, result)
    sample: dict[str, NDArray] = {
        "maps": np.where(mask[..., None], dec.maps, 0.0).astype(np.float32),
        "mask": mask,
        "normal": np.where(mask[..., None], result.normal, 0.0).astype(np.float32),
        "depth": np.where(mask, result.depth, 0.0).astype(np.float32),
        **{k: np.where(mask[..., None] if v.ndim == 3 else mask, v, 0.0).astype(np.float32) for k, v in gt.items()},
    }
    if keep_stokes:
        sample["stokes"] = result.stokes
    if keep_raw:
        sample["raw"] = raws
    materials = {m.name: m for m in spec.materials}
    meta = {
        "rig": spec.rig.to_dict(),
        "camera_model": model.to_dict(),
        "objects": [
            {"name": o.name, "mesh": o.mesh, "to_world": np.asarray(o.to_world).tolist(), "material": o.material}
            for o in spec.objects
        ],
        "materials": {
            name: {"kind": m.kind, "albedo": list(m.albedo), "roughness": m.roughness, "metallic": m.metallic}
            for name, m in materials.items()
        },
        "seed": int(spec.seed),
        "window": result.window.to_dict(),
        "intrinsics": result.window.intrinsics(spec.rig.camera).tolist(),
        "variant": result.variant,
        "seconds": {**result.seconds, "camera_and_decode": t_camera},
        "mask_fraction": float(mask.mean()),
    }
    return sample, meta


# --------------------------------------------------------------------------- RGB preview


@dataclass(frozen=True)
class PreviewSettings:
    """How to render the RGB preview of a scene (:func:`render_preview`).

    Attributes:
        resolution: film ``(W, H)``, a width (sensor aspect), or None (the camera's sensor size).
        spp: samples per pixel.
        max_depth: path length limit.
        display: include the rig's display as an (unpolarized) light.
        variant: Mitsuba RGB variant, or None (:func:`choose_rgb_variant`).
        seed: sampler seed.
    """

    resolution: tuple[int, int] | int | None = 256
    spp: int = 64
    max_depth: int = 8
    display: bool = True
    variant: str | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if self.spp < 1:
            raise ValueError(f"spp must be >= 1, got {self.spp}")
        if self.max_depth < 1:
            raise ValueError(f"max_depth must be >= 1, got {self.max_depth}")


@dataclass
class PreviewResult:
    """An RGB preview render: ``rgb (H, W, 3)`` linear radiance, ``alpha (H, W)`` coverage, the scene dict."""

    rgb: NDArray[np.float32]
    alpha: NDArray[np.float32]
    scene: dict
    variant: str
    seconds: float

    @property
    def mask(self) -> NDArray[np.bool_]:
        """Pixels at least half covered by geometry (objects, or lights seen by the camera)."""
        return self.alpha >= 0.5


def render_preview(spec: SceneSpec, files_dir, settings: PreviewSettings = PreviewSettings()) -> PreviewResult:
    """Render the RGB (non-polarized) preview of a scene spec with Mitsuba.

    Args:
        spec: the scene; its lights and environment are used, and its rig camera.
        files_dir: folder for the files the scene refers to (converted meshes, display pattern).
        settings: resolution, samples, display on/off.
    """
    variant = settings.variant or choose_rgb_variant()
    mi = _set_variant(variant)
    t0 = time.perf_counter()
    scene = ms.preview_scene_dict(
        spec, files_dir, resolution=settings.resolution, spp=settings.spp, max_depth=settings.max_depth,
        display=settings.display,
    )  # fmt: skip
    img = np.asarray(mi.render(mi.load_dict(scene), seed=int(settings.seed), spp=settings.spp), dtype=np.float32)
    return PreviewResult(
        rgb=img[..., :3].copy(), alpha=img[..., 3].copy(), scene=scene, variant=variant,
        seconds=time.perf_counter() - t0,
    )  # fmt: skip
