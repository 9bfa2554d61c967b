"""Spectral-polarized cross-check renderer: one ``*_spectral_polarized`` pass for all colour channels.

The default renderer (:func:`blender_addon.core.render.render_stokes`) multiplexes the colour
channels with one ``*_mono_polarized`` pass per channel. :func:`render_stokes_spectral` renders
the same scene (:func:`~blender_addon.core.mitsuba_scene.scene_dict`) once in
``llvm_ad_spectral_polarized`` (or ``scalar_spectral_polarized``) and returns the same
:class:`~blender_addon.core.passes.RenderResult`, for cross-checks
(``tests/blender_addon/core/test_spectral.py``) and as the fallback without the LLVM backend.

Spectra (what the display emits and what the materials do at each wavelength):

* **Display.** The whole active area emits the pattern through a ``d65`` texture wrapping an RGB
  ``bitmap`` (nearest filtering, :func:`display_radiance`): each texel emits ``D65(lambda) x
  upsample(rgb)(lambda)``, whose sRGB rendering is the RGB value itself. The upsampling clamps
  texels to [0, 1], so the sheet's doubling and ``display.radiance`` go into the ``scale``. The
  polarizer sheet and a curved display's strips are the mono passes'
  (:func:`~blender_addon.core.mitsuba_scene.display_shapes`); any pattern works.
* **pplastic.** ``diffuse_reflectance`` is the albedo as an ``rgb`` reflectance (Mitsuba's
  smooth, bounded upsampling; a grey albedo is flat). ``int_ior`` is wavelength independent.
* **conductor.** ``eta`` and ``k`` are ``irregular`` spectra, piecewise linear through the
  channel values at :data:`~blender_addon.core.mitsuba_scene.CHANNEL_WAVELENGTHS_NM` and constant
  beyond them (360-830 nm): the mono passes' values at their wavelengths (an ``rgb`` value would
  be clamped to [0, 1] as a reflectance).
* **measured.** ``measured_polarized`` without ``wavelength``: the table's own bands.

Convention: the ``stokes`` integrator sends each Stokes component through the spectrum -> linear
sRGB conversion (signed); with the ``luminance`` film the channel layout is the mono passes'
(``[Y, S0.RGB, S1.RGB, S2.RGB, S3.RGB, AOVs...]``), so the AOVs come out as in
:func:`~blender_addon.core.render.render_stokes`. How a spectral channel differs from a mono
pass physically, and the cost: docs/measurements/blender_addon.md.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from . import mitsuba_scene as ms
from . import passes

if TYPE_CHECKING:
    from pbrdf.sensor.rig import DisplaySpec

    from .spec import MaterialSpec, SceneSpec

__all__ = ["SPECTRAL_VARIANTS", "choose_spectral_variant", "display_radiance", "bsdf_dict", "render_stokes_spectral"]

#: Mitsuba variants :func:`render_stokes_spectral` renders in (the PyPI wheel's; CUDA untested).
SPECTRAL_VARIANTS = ("llvm_ad_spectral_polarized", "scalar_spectral_polarized", "cuda_ad_spectral_polarized")
#: Spectral range of Mitsuba's colour matching functions (nm); spectra are defined over it.
_LAMBDA_RANGE_NM = (360.0, 830.0)
#: Film channels before the AOVs: Y, then S0..S3 x (R, G, B).
_STOKES_CHANNELS = 13


def choose_spectral_variant() -> str:
    """``llvm_ad_spectral_polarized`` when Dr.Jit's LLVM backend works, else ``scalar_spectral_polarized``."""
    return passes.choose_variant("llvm_ad_spectral_polarized")


def display_radiance(display: DisplaySpec) -> dict:
    """Emitter radiance texture of the display pattern for spectral variants.

    ``d65(bitmap)``: each texel emits D65 times the smooth upsampled spectrum of its RGB value, so
    that the film's sRGB conversion returns the RGB value; the doubling for the polarizer sheet and
    ``display.radiance`` sit in the ``scale`` (the bitmap's upsampling clamps to [0, 1]).
    """
    import mitsuba as mi  # noqa: PLC0415

    # Bitmap row 0 is v = 0, the bottom of the emitting surface; the pattern's row 0 is the top.
    pattern = np.ascontiguousarray(np.flipud(display.pattern_image()), dtype=np.float32)
    return {
        "type": "d65",
        "scale": 2.0 * display.radiance,
        "nested": {
            "type": "bitmap",
            "bitmap": mi.Bitmap(pattern),
            "filter_type": "nearest",
            "wrap_mode": "clamp",
        },
    }


def _channel_spectrum(values: tuple[float, float, float]) -> dict | float:
    """Piecewise-linear spectrum through the (R, G, B) values at the channel wavelengths.

    Constant below the blue and above the red wavelength; a plain float when the values are equal.
    """
    if values[0] == values[1] == values[2]:
        return float(values[0])
    r, g, b = (float(v) for v in values)
    wl_r, wl_g, wl_b = ms.CHANNEL_WAVELENGTHS_NM
    lo, hi = _LAMBDA_RANGE_NM
    nodes = [(lo, b), (wl_b, b), (wl_g, g), (wl_r, r), (hi, r)]
    return {
        "type": "irregular",
        "wavelengths": ", ".join(f"{w:g}" for w, _ in nodes),
        "values": ", ".join(repr(v) for _, v in nodes),
    }


def _spectrum(values: tuple[float, float, float], kind: str) -> dict | float:
    """RGB reflectances as an ``rgb`` spectrum, IORs through :func:`_channel_spectrum`.

    (An ``rgb`` IOR would be squashed into [0, 1] as if it were a reflectance.)
    """
    if kind == "reflectance":
        return {"type": "rgb", "value": [float(a) for a in values]}
    return _channel_spectrum(values)


def bsdf_dict(material: MaterialSpec) -> dict:
    """The material's BSDF for spectral variants (:func:`mitsuba_scene.bsdf_dict` with spectra)."""
    return ms.bsdf_dict(material, None, spectrum=_spectrum)


def render_stokes_spectral(
    spec: SceneSpec, settings: passes.RenderSettings | None = None, *, variant: str | None = None
) -> passes.RenderResult:
    """Render the Stokes images (per colour channel) and AOVs in one spectral-polarized pass.

    Same scene, crop window, AOVs and result type as :func:`render.render_stokes`; see the module
    docstring for the spectra of the display and the materials.

    Args:
        spec: validated scene spec.
        settings: resolution, samples (``spp`` for the single pass), cropping, integrator
            (default :class:`passes.RenderSettings`); ``settings.variant`` is used when it names
            a spectral variant.
        variant: Mitsuba variant (one of :data:`SPECTRAL_VARIANTS`); default
            :func:`choose_spectral_variant`.

    Returns:
        :class:`passes.RenderResult`; ``seconds`` holds ``load`` and ``pass_spectral``.

    Raises:
        ValueError: ``variant`` is not a spectral-polarized variant.
    """
    settings = settings or passes.RenderSettings()
    if variant is None and settings.variant is not None and "spectral" in settings.variant:
        variant = settings.variant
    variant = variant or choose_spectral_variant()
    if variant not in SPECTRAL_VARIANTS:
        raise ValueError(f"variant must be one of {SPECTRAL_VARIANTS}, got {variant!r}")
    mi = passes.set_variant(variant)
    rig = spec.rig
    cam = rig.camera
    meshes = passes.world_meshes(spec)
    window = passes.render_window(spec, settings, meshes)
    materials = {m.name: m for m in spec.materials}
    names = [f"object_{i}" for i in range(len(spec.objects))]
    integrator = settings.integrator_for(sheet=True)  # spectral variants keep the sheet
    max_depth = settings.max_depth
    if max_depth is None:  # chosen from the scene, as the mono passes do
        max_depth = ms.auto_max_depth(meshes, integrator)

    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    objs = {
        name: ms.mesh_object(name, v, f, n, bsdf_dict(materials[obj.material]), two_sided=two)
        for name, obj, (v, f, n, two) in zip(names, spec.objects, meshes, strict=True)
    }
    # The whole display emits the spectral texture (the mono passes' raw bitmap throws in spectral variants).
    scene = mi.load_dict(
        ms.scene_dict(
            rig.display, cam, window, objs, None, spp=settings.spp, max_depth=max_depth, integrator=integrator,
            sampler=settings.sampler, display_radiance=display_radiance(rig.display),
        )
    )  # fmt: skip
    seconds["load"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    img = np.asarray(mi.render(scene, seed=(int(spec.seed) * 3) % 2**32, spp=settings.spp))
    seconds["pass_spectral"] = time.perf_counter() - t0
    if img.shape[-1] != _STOKES_CHANNELS + 11:
        raise RuntimeError(f"unexpected film layout: {img.shape[-1]} channels")
    h, w = img.shape[:2]
    # [Y, S0.RGB, S1.RGB, S2.RGB, S3.RGB]: channel 1 + 3 i + c is S_i of colour c.
    stokes = img[..., 1:_STOKES_CHANNELS].reshape(h, w, 4, 3).transpose(0, 1, 3, 2)
    aovs = passes.aov_result(img[..., _STOKES_CHANNELS:], scene, spec, names, [m[3] for m in meshes])
    return passes.RenderResult(
        stokes=np.ascontiguousarray(stokes, dtype=np.float32),
        window=window,
        variant=variant,
        seconds=seconds,
        integrator=integrator,
        display="sheet",
        **aovs,
    )
