"""What every polarized render pass shares: settings, result, Mitsuba variant, crop window, AOVs.

:mod:`.render` (one mono pass per colour channel) and :mod:`.spectral` (one spectral pass) both
build on this module and on :mod:`.mitsuba_scene`; neither imports the other's internals.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from . import mitsuba_scene as ms

if TYPE_CHECKING:
    from .spec import SceneSpec

__all__ = [
    "RenderSettings",
    "RenderResult",
    "choose_variant",
    "choose_rgb_variant",
    "set_variant",
    "world_meshes",
    "render_window",
    "aov_result",
    "INTEGRATORS",
]

_VARIANT_CACHE: dict[str, str] = {}


@dataclass(frozen=True)
class RenderSettings:
    """How to render one sample.

    Attributes:
        resolution: output size R (the decoded maps are R x R; the raw mosaic 2R x 2R).
        spp: samples per pixel per colour pass.
        max_depth: path length limit, or None (default) to choose it from the scene
            (:func:`.mitsuba_scene.auto_max_depth`: direct light only for one closed convex
            object, which sees neither itself nor another, else one interreflection). 2 is direct
            light only and 3 adds one interreflection, except for ``path`` through the polarizer
            sheet, which counts the sheet as a bounce and needs one more.
        crop: render only the objects' screen-space bounding box (True) or the full sensor at
            the same sampling (benchmarks).
        margin: border around the bounding box, as a fraction of its size.
        display: ``"emitter"`` (default): the display as :mod:`.polarized_display`'s polarized
            emitter where the display allows it (flat, built-in pattern;
            :func:`.mitsuba_scene.polarized_emitter_possible`), else with the sheet;
            ``"sheet"``: always the unpolarized emitter behind a ``polarizer`` sheet (the
            reference model; same images to noise).
        integrator: ``"auto"`` (default: without the sheet ``direct`` where direct light is all
            (``max_depth`` 2), else ``path``; ``volpath`` with the sheet), ``"direct"`` (without
            the sheet only), ``"volpath"`` or ``"path"`` (with the sheet for benchmarks only: it
            cannot see the display through the sheet with next-event estimation).
        sampler: Mitsuba sampler. ``multijitter`` (stratified, default): 2.9 % relative error at
            16 spp where ``independent`` has 10.5 % (docs/measurements/headless.md, samplers).
        variant: Mitsuba variant, or None to choose (:func:`choose_variant`).
        noise: simulate sensor noise.
    """

    resolution: int = 384
    spp: int = 32
    max_depth: int | None = None
    crop: bool = True
    margin: float = 0.06
    display: str = "emitter"
    integrator: str = "auto"
    sampler: str = "multijitter"
    variant: str | None = None
    noise: bool = True

    def __post_init__(self) -> None:
        if self.resolution < 8 or self.resolution % 2:
            raise ValueError(f"resolution must be even and >= 8, got {self.resolution}")
        if self.spp < 1:
            raise ValueError(f"spp must be >= 1, got {self.spp}")
        if self.max_depth is not None and self.max_depth < 1:
            raise ValueError(f"max_depth must be None or >= 1, got {self.max_depth}")
        if self.integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {INTEGRATORS}, got {self.integrator!r}")
        if self.display not in ("emitter", "sheet"):
            raise ValueError(f"display must be 'emitter' or 'sheet', got {self.display!r}")

    def integrator_for(self, sheet: bool, max_depth: int | None = None) -> str:
        """The integrator used with or without the polarizer sheet, and at ``max_depth`` if known.

        ``"auto"`` is ``volpath`` with the sheet, and without it ``direct`` at the direct-light
        depth (``max_depth`` 2) and ``path`` otherwise.
        """
        if self.integrator == "direct" and sheet:
            raise ValueError("integrator 'direct' cannot light the scene through the polarizer sheet; use 'volpath'")
        if self.integrator != "auto":
            return self.integrator
        if sheet:
            return "volpath"
        return "direct" if max_depth == ms.DIRECT_LIGHT_DEPTH["volpath"] else "path"


#: Accepted ``RenderSettings.integrator`` values.
INTEGRATORS = ("auto", "direct", "path", "volpath")


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
        seconds: wall time per pass (``load``, ``pass_R`` ...) and, in JIT variants, the part
            spent on kernels new to the process, compiled or loaded from Dr.Jit's disk cache
            (``jit_compile``; 0 when every kernel was compiled by an earlier sample).
        max_depth: the path length limit rendered with (chosen from the scene when the
            settings left it None).
        integrator: the integrator rendered with (``path`` or ``volpath``).
        display: the display model rendered with: ``"emitter"`` (:mod:`.polarized_display`)
            or ``"sheet"``.
        truth: with textured materials, the material maps of what was rendered
            (:func:`.texture_truth.truth_pass`: ``albedo (H, W, 3)``, ``roughness``, ``metallic``
            filtered over each pixel as the image is); None for per-object constants.
    """

    stokes: NDArray[np.float32]
    normal: NDArray[np.float32]
    depth: NDArray[np.float32]
    coverage: NDArray[np.float32]
    object_index: NDArray[np.int32]
    window: ms.CropWindow
    variant: str
    seconds: dict = field(default_factory=dict)
    max_depth: int | None = None
    integrator: str = ""
    display: str = ""
    truth: dict | None = None

    @property
    def mask(self) -> NDArray[np.bool_]:
        """Pixels at least half covered by an object."""
        return self.coverage >= 0.5


def choose_variant(preferred: str = "llvm_ad_mono_polarized") -> str:
    """Pick the Mitsuba variant: the LLVM mono-polarized one when Dr.Jit's LLVM backend works.

    LLVM older than 16 is rejected (LLVM 15 aborts on Mitsuba's polarized kernels; ``make
    setup`` installs libllvm19). Without it, falls back to ``scalar_spectral_polarized`` with a
    warning (much slower; the display pattern must be the built-in one there).

    Args:
        preferred: a Mitsuba variant name or an alias (``headless/render.py --variant``):
            ``auto`` (``cuda_ad_mono_polarized`` when Dr.Jit's CUDA backend works and Mitsuba
            has that variant, else as ``llvm``), ``llvm`` (``llvm_ad_mono_polarized``), ``cuda``
            (``cuda_ad_mono_polarized``), ``scalar`` (``scalar_spectral_polarized``).

    Raises:
        RuntimeError: the variant is not built into Mitsuba, or a CUDA variant without a working
            CUDA backend.
    """
    if preferred in _VARIANT_CACHE:
        return _VARIANT_CACHE[preferred]
    import mitsuba as mi  # noqa: PLC0415

    aliases = {
        "llvm": "llvm_ad_mono_polarized",
        "cuda": "cuda_ad_mono_polarized",
        "scalar": "scalar_spectral_polarized",
    }
    variant = aliases.get(preferred, preferred)
    if variant == "auto":
        cuda = "cuda_ad_mono_polarized"
        variant = cuda if cuda in mi.variants() and cuda_ok() else aliases["llvm"]
    if variant.startswith("cuda") and not cuda_ok():
        raise RuntimeError(f"Mitsuba variant {variant!r} needs Dr.Jit's CUDA backend (an NVIDIA GPU and driver)")
    if variant.startswith("llvm"):
        if not llvm_ok():
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


def cuda_ok() -> bool:
    """Dr.Jit's CUDA backend works (an NVIDIA GPU with its driver)."""
    import drjit as dr  # noqa: PLC0415

    return bool(dr.has_backend(dr.JitBackend.CUDA))


def llvm_ok() -> bool:
    """Dr.Jit's LLVM backend works and is LLVM >= 16 (older versions abort on polarized kernels)."""
    import drjit as dr  # noqa: PLC0415

    return bool(dr.has_backend(dr.JitBackend.LLVM)) and tuple(dr.detail.llvm_version()) >= (16, 0, 0)


def choose_rgb_variant() -> str:
    """``llvm_ad_rgb`` when the LLVM backend works (:func:`choose_variant`'s test), else ``scalar_rgb``."""
    import mitsuba as mi  # noqa: PLC0415

    for variant in ("llvm_ad_rgb", "scalar_rgb"):
        if variant in mi.variants() and (not variant.startswith("llvm") or llvm_ok()):
            return variant
    raise RuntimeError(f"no RGB Mitsuba variant is available; have {mi.variants()}")


def set_variant(variant: str):
    """Switch Mitsuba to ``variant`` (if needed), errors-only logging; returns the ``mitsuba`` module."""
    import mitsuba as mi  # noqa: PLC0415

    if mi.variant() != variant:
        mi.set_variant(variant)
    mi.set_log_level(mi.LogLevel.Error)
    return mi


def world_meshes(spec: SceneSpec, *, uvs: bool = False) -> list[tuple]:
    """(vertices, faces, shading normals, two-sided[, uvs]) of every object, in world coordinates.

    The meshes come from :func:`.assets.load_mesh` (its normals are the shading normals the
    ground truth reports); two-sided marks open meshes, whose back faces may be seen. With
    ``uvs``, a fifth element: OpenGL UVs ``(N, 2)`` for objects whose material has textures
    (meshes without UVs are unwrapped by :func:`.assets.ensure_uv`), None for the others, whose
    meshes stay as they are.
    """
    from . import assets  # noqa: PLC0415

    materials = {m.name: m for m in spec.materials}
    out = []
    for obj in spec.objects:
        mesh = assets.load_mesh(obj.mesh)
        mat = materials.get(obj.material)
        uv = None
        if uvs and mat is not None and mat.textures is not None and mat.textures.slots():
            mesh = _with_uv(mesh)
            uv = np.asarray(mesh.visual.uv, dtype=np.float64)
        m = np.asarray(obj.to_world, dtype=np.float64)
        v = np.asarray(mesh.vertices) @ m[:3, :3].T + m[:3, 3]
        n = np.asarray(mesh.vertex_normals) @ np.linalg.inv(m[:3, :3])  # inverse-transpose, row vectors
        n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
        faces = np.asarray(mesh.faces)
        if np.linalg.det(m[:3, :3]) < 0:  # a mirroring pose turns the winding around
            faces = faces[:, ::-1]
        two = bool(mesh.metadata.get("two_sided", False))
        out.append((v, faces, n, two, uv) if uvs else (v, faces, n, two))
    return out


_UV_MESHES: dict[int, tuple] = {}


def _with_uv(mesh):
    """The mesh with UVs (:func:`.assets.ensure_uv`, its metadata kept), unwrapped once per cached mesh."""
    from . import assets  # noqa: PLC0415

    hit = _UV_MESHES.get(id(mesh))
    if hit is not None and hit[0] is mesh:
        return hit[1]
    out = assets.ensure_uv(mesh)
    if out is not mesh:
        out.metadata.update(mesh.metadata)
    if len(_UV_MESHES) >= 32:
        _UV_MESHES.pop(next(iter(_UV_MESHES)))
    _UV_MESHES[id(mesh)] = (mesh, out)
    return out


def render_window(spec: SceneSpec, settings: RenderSettings, meshes: list | None = None) -> ms.CropWindow:
    """The crop window around the objects, or the whole sensor at the same sampling.

    With ``settings.crop`` False the object covers the same pixels as in the crop, which sits at
    the crop window's ``offset`` inside the full film.
    """
    cam = spec.rig.camera
    meshes = world_meshes(spec) if meshes is None else meshes
    uv = np.concatenate([cam.project(m[0])[0] for m in meshes])
    window = ms.crop_window(cam, uv, settings.resolution, margin=settings.margin)
    if settings.crop:
        return window
    return ms.CropWindow(window.binning, window.film_size, (0, 0), window.film_size)


def aov_result(
    aov: NDArray, scene, spec: SceneSpec, names: list[str], two_sided: list[bool] | None = None
) -> dict[str, NDArray]:
    """Coverage, camera-frame normals, depth and object index from the AOV block of a render.

    Args:
        aov: ``(H, W, 11)`` channels after the Stokes block: integrator RGBA, ``nn.XYZ``
            (shading normal), ``pp.XYZ`` (position), ``si.I`` (shape index), each averaged over
            the pixel's samples (so divided by the coverage here).
        scene: the Mitsuba scene that produced them (for the shape ids).
        spec: the scene spec (camera pose).
        names: Mitsuba shape names of ``spec.objects`` in order.
        two_sided: per object, whether it is rendered two-sided; there a normal facing away
            from the camera (a back face seen) is flipped, as Mitsuba's ``twosided`` flips the
            shading frame.
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
    if two_sided is not None and any(two_sided):
        seen_back = np.einsum("hwk,hwk->hw", normal, -p_cam) < 0
        flip = seen_back & np.isin(index, np.flatnonzero(np.asarray(two_sided, dtype=bool)))
        normal[flip] *= -1.0
    return {
        "normal": normal.astype(np.float32),
        "depth": depth.astype(np.float32),
        "coverage": coverage.astype(np.float32),
        "object_index": index,
    }
