"""Polarized rendering of a scene spec with Mitsuba 3, and the synthetic capture built from it.

:func:`render_stokes` renders the Stokes images per colour channel (one ``*_mono_polarized``
pass per channel, only the object's screen-space crop) plus ground-truth AOVs.
:func:`synthesize_sample` then sends the Stokes images through the foundation's camera model
(QWP, micro-polarizers, mosaic, noise, 12-bit HDR brackets) and decoder, exactly as a real
capture, and assembles a dataset sample (:mod:`pbrdf.data.dataset` format) with the ground truth.

Grids: Stokes and AOVs are rendered at the sample resolution R (one rendered pixel per 2x2
raw block); the raw mosaic is 2R x 2R (the Stokes value is held constant over each block) and
the decoder's ``"half"`` grid brings the nine maps back to R x R, pixel-aligned with the ground
truth.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from pbrdf.sensor import camera as pcamera
from pbrdf.sensor import decode as pdecode

from . import mitsuba_preview, textured_bsdf
from . import mitsuba_scene as ms
from .passes import (
    RenderResult,
    RenderSettings,
    aov_result,
    choose_rgb_variant,
    choose_variant,
    render_window,
    set_variant,
    world_meshes,
)
from .spectral import render_stokes_spectral
from .texture_truth import mapped_normals, needs_truth_pass, truth_pass

if TYPE_CHECKING:
    from collections.abc import Iterator

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

#: Render the colour passes of textured scenes with Dr.Jit's wavefront (non-symbolic) calls and
#: loops. Symbolic mode compiles one megakernel per combination of BSDF trees, and textured
#: scenes rarely share one: each sample compiled its own (20-50 s at 128 px on 2 cores). Wavefront
#: mode compiles small per-instance kernels that later scenes reuse, renders the same images bit
#: for bit, and costs about as much per pass (docs/measurements/headless.md, 2026-11-27). The
#: truth pass stays symbolic: its AOV integrator's shading normal comes out wrong in wavefront
#: mode (measured: x component off, ``|n|`` 0.977) on Mitsuba 3.9.
WAVEFRONT_TEXTURED = True
#: Wavefront mode keeps every lane's state in memory between its kernels (about 2 KB per camera
#: sample): renders with more samples than this (width x height x spp) stay symbolic. A 192 px
#: dataset sample at 16 spp has 0.6 M; a 384 px 1024-spp reference in 64-spp chunks (9.4 M) ran
#: out of the 24 GB of a 2-core machine.
WAVEFRONT_MAX_SAMPLES = 2**21


def render_stokes(spec: SceneSpec, settings: RenderSettings | None = None) -> RenderResult:
    """Render the Stokes images (per colour channel) and ground-truth AOVs of a scene spec.

    Between the channel passes only parameters change where the plugins allow it; scenes with
    table materials (``measured_polarized`` has no parameters) are rebuilt per channel, after
    the previous one is freed, so that Dr.Jit's registry hands out the same instance ids, which
    its kernels depend on. With the sensor and material choices of :mod:`.mitsuba_scene`, the
    kernels compiled for the first sample of a process serve every later one with the same
    resolution, ``spp``, ``max_depth`` and BSDF types (``seconds["jit_compile"]`` is then 0).
    The display is :mod:`.polarized_display`'s emitter where it can be (``settings.display``),
    and only the first pass renders the AOVs.

    Args:
        spec: validated scene spec (rig, objects, materials).
        settings: resolution, samples, cropping, display model, integrator, variant;
            ``max_depth`` None chooses it from the scene (:func:`.mitsuba_scene.auto_max_depth`).

    Returns:
        :class:`RenderResult` on the crop window, with the ``max_depth``, integrator and display
        model used.
    """
    settings = settings or RenderSettings()
    variant = settings.variant or choose_variant()
    mi = set_variant(variant)
    textured = needs_truth_pass(spec)
    meshes = world_meshes(spec, uvs=textured)
    rig = spec.rig
    spectral = "spectral" in variant
    polarized_emitter = settings.display == "emitter" and not spectral and ms.polarized_emitter_possible(rig.display)
    sheet = not polarized_emitter
    max_depth = settings.max_depth
    if max_depth is None:
        # Only path through the sheet counts the sheet as a bounce; without it every integrator needs 2.
        max_depth = ms.auto_max_depth(meshes, settings.integrator_for(sheet) if sheet else "path", sheet=sheet)
    integrator = settings.integrator_for(sheet, max_depth)
    if spectral:  # the fallback without LLVM, and cross-checks
        if textured:
            log.warning("textures are rendered in the mono-polarized variants only; %s renders constants", variant)
        result = render_stokes_spectral(spec, dataclasses.replace(settings, max_depth=max_depth), variant=variant)
        result.max_depth = max_depth
        return result
    window = render_window(spec, settings, meshes)
    scenes = _ChannelScenes(spec, meshes, window, settings, max_depth, integrator, polarized_emitter)
    lanes = window.size[0] * window.size[1] * settings.spp
    wavefront = textured and WAVEFRONT_TEXTURED and lanes <= WAVEFRONT_MAX_SAMPLES
    stokes, aovs, seconds = _render_channels(mi, scenes, wavefront=wavefront)
    truth = None
    if textured:  # the material maps of what was rendered (:mod:`.texture_truth`)
        seed = (int(spec.seed) * 3) % 2**32  # the first colour pass's: its sample positions
        truth, truth_aovs, _, seconds["truth"] = truth_pass(spec, meshes, window, settings, scenes.names, seed)
        mask = aovs["coverage"] >= 0.5
        aovs["normal"] = mapped_normals(spec, truth_aovs, aovs["object_index"], aovs["normal"], mask)
    return RenderResult(
        stokes=stokes, window=window, variant=variant, seconds=seconds, max_depth=max_depth,
        integrator=integrator, display="emitter" if polarized_emitter else "sheet", truth=truth, **aovs,
    )  # fmt: skip


@dataclass
class _ChannelScenes:
    """The Mitsuba scene of each colour channel's pass: built anew, or switched by parameter updates."""

    spec: SceneSpec
    meshes: list
    window: ms.CropWindow
    settings: RenderSettings
    max_depth: int
    integrator: str
    polarized_emitter: bool

    def __post_init__(self) -> None:
        self.materials = {m.name: m for m in self.spec.materials}
        self.names = [f"object_{i}" for i in range(len(self.spec.objects))]
        # Direct light only comes from the linearly polarized display (S3 = 0): tables skip a column.
        self.linear_light = self.integrator == "direct"

    def build(self, channel: int):
        """The loaded scene of ``channel``."""
        import mitsuba as mi  # noqa: PLC0415

        objs = {
            name: ms.mesh_object(
                name, m[0], m[1], m[2],
                _bsdf_dict(self.materials[obj.material], channel, self.linear_light),
                two_sided=m[3], uvs=m[4] if len(m) > 4 else None,
            )
            for name, obj, m in zip(self.names, self.spec.objects, self.meshes, strict=True)
        }  # fmt: skip
        s = self.settings
        return mi.load_dict(
            ms.scene_dict(
                self.spec.rig.display, self.spec.rig.camera, self.window, objs, channel,
                spp=s.spp, max_depth=self.max_depth, integrator=self.integrator, sampler=s.sampler,
                polarized_emitter=self.polarized_emitter,
            )
        )  # fmt: skip

    def updates(self, channel: int, params) -> dict | None:
        """Parameter updates that switch the scene of ``params`` (``mi.traverse``) to ``channel``; None if none can."""
        updates = ms.display_updates(self.spec.rig.display, channel, params)
        for name, obj, mesh in zip(self.names, self.spec.objects, self.meshes, strict=True):
            mat = self.materials[obj.material]
            if textured_bsdf.has_textures(mat):
                u = textured_bsdf.channel_updates(mat, channel, f"{name}.bsdf.brdf_0" if mesh[3] else f"{name}.bsdf")
            else:
                u = ms.channel_updates(name, mat, channel, two_sided=mesh[3])
            if u is None or updates is None or not all(k in params for k in u):
                return None
            updates.update(u)
        return updates


def _bsdf_dict(material, channel: int, linear_light: bool) -> dict:
    """The material's BSDF for one colour channel: :mod:`.textured_bsdf` with textures, else its constants."""
    if textured_bsdf.has_textures(material):
        return textured_bsdf.bsdf_dict(material, channel, linear_light=linear_light)
    return ms.bsdf_dict(material, channel, linear_light=linear_light)


def _render_channels(
    mi, scenes: _ChannelScenes, *, wavefront: bool = False
) -> tuple[NDArray[np.float32], dict[str, NDArray], dict[str, float]]:
    """The three colour passes: Stokes ``(H, W, 3, 4)``, the AOVs of the first pass, and the seconds spent.

    A scene that cannot be switched by parameter updates is freed before the next one is built, so that
    Dr.Jit's registry hands out the same instance ids, which its kernels depend on. With ``wavefront``
    (:data:`WAVEFRONT_TEXTURED`) the colour passes run without AOVs in wavefront mode and the AOVs come
    from a symbolic AOV-only pass at the first pass's seed: the same sample positions, so the same
    values, with a small kernel that does not evaluate BSDFs.
    """
    spec, settings = scenes.spec, scenes.settings
    seconds: dict[str, float] = {}
    w, h = scenes.window.size
    stokes = np.zeros((h, w, 3, 4), dtype=np.float32)
    aovs: dict[str, NDArray] = {}
    with _CompileTimer() as compile_timer:
        t0 = time.perf_counter()
        scene = scenes.build(0)
        params = mi.traverse(scene)
        seconds["load"] = time.perf_counter() - t0
        for c in range(3):
            t0 = time.perf_counter()
            if c > 0:
                updates = scenes.updates(c, params)
                if updates is None:
                    scene = params = None  # freed before the next one is built (see above)
                    scene = scenes.build(c)
                    params = mi.traverse(scene)
                else:
                    params.update(updates)
            # The AOVs come from the first pass; the others skip them (a primary ray and seven
            # film channels less per sample).
            with_aovs = c == 0 and not wavefront
            integ = None if with_aovs else _plain_integrator(scenes.integrator, scenes.max_depth)
            with _wavefront(wavefront):
                img = np.asarray(
                    mi.render(scene, integrator=integ, seed=(int(spec.seed) * 3 + c) % 2**32, spp=settings.spp)
                )
            # Mono layout: [Y, S0 x3, S1 x3, S2 x3, S3 x3, AOVs (first pass)...].
            stokes[:, :, c, :] = img[:, :, [1, 4, 7, 10]]
            if with_aovs:  # AOVs from the first pass, with that scene's shape ids
                aovs = aov_result(img[:, :, 13:], scene, spec, scenes.names, [m[3] for m in scenes.meshes])
            seconds[f"pass_{'RGB'[c]}"] = time.perf_counter() - t0
        if wavefront:  # the AOVs are the same in every channel's scene; its shape ids come with it
            t0 = time.perf_counter()
            img = np.asarray(mi.render(scene, integrator=_aov_integrator(), seed=int(spec.seed) * 3 % 2**32,
                                       spp=settings.spp))  # fmt: skip
            aovs = aov_result(img[:, :, 13:], scene, spec, scenes.names, [m[3] for m in scenes.meshes])
            seconds["aovs"] = time.perf_counter() - t0
    seconds["jit_compile"] = compile_timer.seconds
    return stokes, aovs, seconds


_PLAIN_INTEGRATORS: dict[tuple[str, str, int], object] = {}


def _plain_integrator(integrator: str, max_depth: int):
    """The ``stokes`` integrator without AOVs, one object per variant and setting (its kernels are reused)."""
    import mitsuba as mi  # noqa: PLC0415

    key = (mi.variant(), integrator, max_depth)
    if key not in _PLAIN_INTEGRATORS:
        _PLAIN_INTEGRATORS[key] = mi.load_dict(ms.integrator_dict(integrator, max_depth, aovs=False))
    return _PLAIN_INTEGRATORS[key]


def _aov_integrator():
    """The AOVs of the first pass without its BSDF evaluations, one integrator per variant.

    ``aov`` around Mitsuba's ``depth`` integrator (no BSDF or emitter calls): the film layout and the
    AOV channels equal those of ``aov`` around the colour integrator.
    """
    import mitsuba as mi  # noqa: PLC0415

    key = (mi.variant(), "aovs only", 0)
    if key not in _PLAIN_INTEGRATORS:
        aov = {"type": "aov", "aovs": ms.AOVS, "integrator": {"type": "depth"}}
        _PLAIN_INTEGRATORS[key] = mi.load_dict({"type": "stokes", "nested": aov})
    return _PLAIN_INTEGRATORS[key]


@contextlib.contextmanager
def _wavefront(on: bool) -> Iterator[None]:
    """Dr.Jit's symbolic calls and loops off inside the block (:data:`WAVEFRONT_TEXTURED`), restored after."""
    if not on:
        yield
        return
    import drjit as dr  # noqa: PLC0415

    flags = (dr.JitFlag.SymbolicCalls, dr.JitFlag.SymbolicLoops)
    was = [bool(dr.flag(f)) for f in flags]
    try:
        for f in flags:
            dr.set_flag(f, False)
        yield
    finally:
        for f, w in zip(flags, was, strict=True):
            dr.set_flag(f, w)


class _CompileTimer:
    """Seconds Dr.Jit spent on kernels new to the process inside a ``with`` block.

    New kernels are compiled, or loaded from Dr.Jit's disk cache (then only their code
    generation counts, a fraction of a millisecond); kernels already in memory count nothing.
    Reads and clears Dr.Jit's kernel history (``JitFlag.KernelHistory``), switched on for the
    block and restored after it.
    """

    def __init__(self) -> None:
        self.seconds = 0.0
        self._was_on = False

    def __enter__(self) -> _CompileTimer:
        import drjit as dr  # noqa: PLC0415

        self._was_on = bool(dr.flag(dr.JitFlag.KernelHistory))
        if not self._was_on:
            dr.set_flag(dr.JitFlag.KernelHistory, True)
        return self

    def __exit__(self, *exc) -> None:
        import drjit as dr  # noqa: PLC0415

        history = dr.kernel_history([dr.KernelType.JIT])  # also clears it
        self.seconds = sum(
            (k.get("codegen_time", 0.0) + k.get("backend_time", 0.0)) / 1000.0
            for k in history
            if not k.get("cache_hit") or k.get("cache_disk")
        )
        if not self._was_on:
            dr.set_flag(dr.JitFlag.KernelHistory, False)


def ground_truth(spec: SceneSpec, result: RenderResult) -> dict[str, NDArray]:
    """Material maps: albedo (H,W,3), roughness, metallic.

    Textured scenes: the truth pass's maps (``result.truth``, the textures at the rendered hits,
    filtered over each pixel as the image is); others: the per-object Disney parameters.
    """
    if result.truth is not None:
        return {k: np.asarray(result.truth[k], np.float32) for k in ("albedo", "roughness", "metallic")}
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
    decode_model: pcamera.CameraModel | None = None,
) -> tuple[dict[str, NDArray], dict]:
    """Camera model + decode on rendered Stokes images -> dataset sample and metadata.

    The raws are simulated with the spec's camera model; ``decode_model`` (default: the same) is
    the one the decoder assumes, e.g. the nominal rig's for a scene with drawn imperfections
    (:mod:`pbrdf.sensor.rig_jitter`). The sidecar's ``camera_model`` is the decoder's.

    Returns:
        ``(sample, metadata)`` in :mod:`pbrdf.data.dataset` format: ``maps`` (H,W,9), ``mask``,
        ``normal``, ``albedo``, ``roughness``, ``metallic``, ``depth``, ``object`` (+ ``stokes``,
        ``raw``); the ground truth covers every object pixel, the mask only decoded ones.
    """
    model = spec.rig.camera.model
    t0 = time.perf_counter()
    # Hold each rendered Stokes vector over its 2x2 raw block.
    up = np.repeat(np.repeat(result.stokes, 2, axis=0), 2, axis=1)
    raws = pcamera.simulate_capture(up, model, rng=rng, noise=noise)
    model = model if decode_model is None else decode_model
    dec = pdecode.decode(raws, model, grid="half")
    t_camera = time.perf_counter() - t0
    # Ground truth lives on the object coverage; the training mask also needs a decoded value.
    cover = result.mask & (result.object_index >= 0)
    mask = cover & dec.mask
    gt = ground_truth(spec, result)
    sample: dict[str, NDArray] = {
        "maps": np.where(mask[..., None], dec.maps, 0.0).astype(np.float32),
        "mask": mask,
        "normal": np.where(cover[..., None], result.normal, 0.0).astype(np.float32),
        "depth": np.where(cover, result.depth, 0.0).astype(np.float32),
        "object": np.where(cover, result.object_index, -1).astype(np.float32),
        **{k: np.where(cover[..., None] if v.ndim == 3 else cover, v, 0.0).astype(np.float32) for k, v in gt.items()},
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
            {
                "name": o.name,
                "mesh": o.mesh,
                "to_world": np.asarray(o.to_world).tolist(),
                "material": o.material,
                "centre": _world_centre(o),
            }  # fmt: skip
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
        "max_depth": result.max_depth,
        "integrator": result.integrator,
        "display_model": result.display,
        "seconds": {**result.seconds, "camera_and_decode": t_camera},
        "mask_fraction": float(mask.mean()),
    }
    return sample, meta


def _world_centre(obj) -> list[float]:
    """World position of an object's bounding-box centre (its mesh file need not be centred)."""
    from . import assets  # noqa: PLC0415

    v = np.asarray(assets.load_mesh(obj.mesh).vertices, dtype=np.float64)
    m = np.asarray(obj.to_world, dtype=np.float64)
    return ((v.min(axis=0) + v.max(axis=0)) / 2 @ m[:3, :3].T + m[:3, 3]).tolist()


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
    mi = set_variant(variant)
    t0 = time.perf_counter()
    scene = mitsuba_preview.preview_scene_dict(
        spec, files_dir, resolution=settings.resolution, spp=settings.spp, max_depth=settings.max_depth,
        display=settings.display,
    )  # fmt: skip
    img = np.asarray(mi.render(mi.load_dict(scene), seed=int(settings.seed), spp=settings.spp), dtype=np.float32)
    return PreviewResult(
        rgb=img[..., :3].copy(), alpha=img[..., 3].copy(), scene=scene, variant=variant,
        seconds=time.perf_counter() - t0,
    )  # fmt: skip
