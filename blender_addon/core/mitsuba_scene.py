"""Scene spec -> Mitsuba 3 scene for one colour channel of the display-camera rig.

The display shows one colour channel of the RGB pattern. Two equivalent models of its
polarization: an unpolarized ``area`` emitter on a rectangle (or a curved strip) with a
``polarizer`` sheet 1 mm in front of it, its radiance doubled for the sheet's 50 % loss (the
reference, and the only one for curved displays and pattern images); or, for flat displays with
the built-in patterns, :mod:`.polarized_display`'s emitter, which emits the light the sheet would
pass and needs no sheet (the default of :mod:`.render`: shadow rays cross no null interface, so
``path`` and ``direct`` work and passes are faster; docs/measurements/headless.md). Objects
carry polarization-aware BSDFs only: ``pplastic`` (Baek et al. 2018) and ``roughconductor`` for
analytic materials and :mod:`.table_bsdf` or ``measured_polarized`` for pBRDF tables
(``principled`` and ``diffuse`` depolarize). The integrator is ``stokes`` around ``direct``,
``path`` or ``volpath`` (with the sheet only ``volpath``: the others cannot send shadow rays
through it), with AOVs for the ground truth.

Spectral multiplexing: one ``*_mono_polarized`` pass per colour channel, each with that
channel's part of the pattern and the material's value at that channel's wavelength
(:data:`CHANNEL_WAVELENGTHS_NM`). Between the passes of one sample only parameters change
(:func:`channel_updates`, :func:`display_updates`). Table materials use :mod:`.table_bsdf`
there (faster than ``measured_polarized``, and its data are parameters); the plugin,
which has no parameters, remains for tables on non-uniform grids (the scene is then reloaded per
channel) and for spectral variants.

Kernel reuse: Dr.Jit compiles every value that is not a JIT parameter into its kernels as a
constant, and compiling one takes seconds (docs/measurements/headless.md). What changes from
sample to sample is kept out of the kernels: the crop window enters through the sensor's
principal point (:func:`sensor_dict`), and the plugin's importance-sampling roughness is rounded
to a few levels (:data:`ALPHA_SAMPLE_LEVELS`). What stays is one kernel per colour channel (the
lit rectangle of the display and a table's wavelength are constants), per set of BSDF types, per
``max_depth`` and per ``spp``, compiled once per process and cached on disk by Dr.Jit.

The RGB (non-polarized) preview of a Blender scene and its XML are in :mod:`.mitsuba_preview`.

Mitsuba is imported lazily: this module can be imported (and its geometry used) without it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from pbrdf.sensor import projection

if TYPE_CHECKING:
    from pbrdf.sensor.rig import CameraSpec, DisplaySpec

    from .spec import MaterialSpec

__all__ = [
    "CHANNEL_WAVELENGTHS_NM",
    "AOVS",
    "CropWindow",
    "crop_window",
    "display_shapes",
    "display_updates",
    "polarized_emitter_possible",
    "sensor_dict",
    "bsdf_dict",
    "mesh_object",
    "mesh_from_arrays",
    "scene_dict",
    "integrator_dict",
    "channel_updates",
    "alpha_sample",
    "is_convex",
    "auto_max_depth",
    "ALPHA_SAMPLE_LEVELS",
    "DIRECT_LIGHT_DEPTH",
    "SHEET_OFFSET",
    "MIN_ALPHA",
    "curved_strip",
    "scalar_transform",
]

#: Wavelength (nm) at which each colour channel (R, G, B) evaluates materials: the approximate
#: emission peaks of the display's primaries. Measured tables interpolate between their bands.
CHANNEL_WAVELENGTHS_NM = (630.0, 532.0, 465.0)
#: AOVs rendered with the first pass: shading normal, position, shape index.
AOVS = "nn:sh_normal,pp:position,si:shape_index"
#: Distance (m) of the polarizer sheet in front of the emitting surface.
SHEET_OFFSET = 1e-3
#: Built-in patterns whose colour channels each light one rectangle of the display.
BUILTIN_RECTANGLE_PATTERNS = ("rgb_halves", "white")
#: Smallest GGX alpha handed to Mitsuba (roughness near 0 makes the microfacet lobes singular).
MIN_ALPHA = 1e-3
#: GGX alphas ``measured_polarized`` importance-samples tables with: the material's alpha rounded
#: to the nearest level in log scale. The plugin compiles its ``alpha_sample`` into the kernel as a
#: constant, so a continuous value would recompile every sample; any value is unbiased.
ALPHA_SAMPLE_LEVELS = (0.05, 0.1, 0.2, 0.4, 0.8)
#: ``max_depth`` of direct light only (camera -> object -> display) per integrator, with the
#: polarizer sheet: ``volpath`` does not count the sheet (a null interface) as a bounce, ``path``
#: does (measured: ``path`` at 2 renders black). Without the sheet (:mod:`.polarized_display`)
#: both need 2. One more adds one interreflection.
DIRECT_LIGHT_DEPTH = {"volpath": 2, "path": 3}
#: Volume over convex-hull volume above which a closed mesh counts as convex.
CONVEX_VOLUME_RATIO = 0.999


@dataclass(frozen=True)
class CropWindow:
    """Which part of the sensor a render covers, at which sampling.

    The render is a ``height x width`` crop, starting at ``offset`` (x, y) in a virtual film of
    ``film_size`` (W, H) pixels that covers the whole sensor with ``binning`` sensor pixels per
    rendered pixel. Rendering only the crop is how the object's screen-space bounding box is
    rendered and nothing else.
    """

    binning: float
    film_size: tuple[int, int]
    offset: tuple[int, int]
    size: tuple[int, int]  # (width, height)

    def intrinsics(self, camera: CameraSpec) -> NDArray[np.float64]:
        """``(3, 3)`` pinhole matrix of the crop in its own pixels (row 0 = top)."""
        film = projection.pinhole_intrinsics(
            camera.focal_length / (camera.pixel_pitch * self.binning), self.film_size[0], self.film_size[1]
        )
        x0, y0 = self.offset
        return projection.crop_intrinsics(film, (y0, x0, y0 + self.size[1], x0 + self.size[0]))

    def fov_x(self, camera: CameraSpec) -> float:
        """Horizontal field of view of the virtual film in radians."""
        return 2 * math.atan(self.film_size[0] * self.binning * camera.pixel_pitch / (2 * camera.focal_length))

    def to_dict(self) -> dict:
        """JSON-friendly form."""
        return {"binning": self.binning, "film_size": list(self.film_size), "offset": list(self.offset),
                "size": list(self.size)}  # fmt: skip


def crop_window(camera: CameraSpec, uv: NDArray, resolution: int, *, margin: float = 0.06) -> CropWindow:
    """Square crop around projected points, rendered at ``resolution`` x ``resolution``.

    The square is always ``resolution`` pixels on a side, also where it extends past the sensor.

    Args:
        camera: the rig camera.
        uv: ``(N, 2)`` sensor pixel coordinates of the object (e.g. its projected vertices).
        resolution: rendered pixels across the square crop.
        margin: extra border, as a fraction of the object's larger side, on each side.
    """
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    side = float(np.max(hi - lo)) * (1 + 2 * margin)
    side = max(side, 8.0)
    binning = side / resolution
    film = (math.ceil(camera.sensor_width_px / binning), math.ceil(camera.sensor_height_px / binning))
    centre = (lo + hi) / 2 / binning
    off = np.round(centre - resolution / 2).astype(int)
    spare = np.array(film) - resolution
    # Inside the film where the square fits; where it does not (objects spread across more than
    # the sensor's shorter side), centred on the film: the square's rows past the sensor edge
    # are rendered like any other (background), so every sample stays R x R.
    off = np.where(spare >= 0, np.clip(off, 0, np.maximum(spare, 0)), spare // 2)
    return CropWindow(binning, film, (int(off[0]), int(off[1])), (resolution, resolution))


def scalar_transform(m: NDArray):
    """A ``(4, 4)`` matrix as Mitsuba's ``ScalarTransform4f`` (imports mitsuba; any variant must be set)."""
    import mitsuba as mi  # noqa: PLC0415

    return mi.ScalarTransform4f(np.asarray(m, dtype=np.float64).tolist())


def curved_strip(display: DisplaySpec, offset: float, segments: int = 64) -> tuple[NDArray, NDArray, NDArray]:
    """Vertices (display-local), faces and UVs of a display curved about its vertical axis.

    The centre of the strip is at the local origin and it bends toward +Z (concave toward the
    viewer); ``offset`` moves it along its normal toward the viewer.
    """
    r = display.curvature_radius
    half_angle = display.width / (2 * r)
    theta = np.linspace(-half_angle, half_angle, segments + 1)
    rad = r - offset
    x = rad * np.sin(theta)
    z = r - rad * np.cos(theta)
    verts, uvs = [], []
    for y, v in ((-display.height / 2, 0.0), (display.height / 2, 1.0)):
        verts.append(np.stack([x, np.full_like(x, y), z], axis=-1))
        uvs.append(np.stack([(theta + half_angle) / (2 * half_angle), np.full_like(x, v)], axis=-1))
    verts_a, uvs_a = np.concatenate(verts), np.concatenate(uvs)
    n = segments + 1
    faces = []
    for i in range(segments):
        faces += [[i, i + 1, n + i + 1], [i, n + i + 1, n + i]]
    return verts_a, np.asarray(faces, dtype=np.uint32), uvs_a


def mesh_from_arrays(name: str, vertices: NDArray, faces: NDArray, props: dict, *, normals=None, uvs=None):
    """A Mitsuba mesh from arrays (no temporary files), in any variant (scalar ones included).

    The buffers take the types ``mi.traverse`` reports (``mi.Float`` is a Python float in scalar
    variants, a Dr.Jit array in JIT ones).
    """
    import mitsuba as mi  # noqa: PLC0415

    p = mi.Properties()
    for k, v in props.items():
        p[k] = v
    mesh = mi.Mesh(
        name, len(vertices), len(faces), props=p,
        has_vertex_normals=normals is not None, has_vertex_texcoords=uvs is not None,
    )  # fmt: skip
    params = mi.traverse(mesh)
    for key, value, dtype in (
        ("vertex_positions", vertices, np.float32),
        ("faces", faces, np.uint32),
        ("vertex_normals", normals, np.float32),
        ("vertex_texcoords", uvs, np.float32),
    ):
        if value is not None:
            params[key] = type(params[key])(np.ascontiguousarray(value, dtype=dtype).ravel())
    params.update()
    return mesh


def _strip_mesh(name: str, verts: NDArray, faces: NDArray, uvs: NDArray, to_world: NDArray, props: dict):
    world = (to_world[:3, :3] @ verts.T).T + to_world[:3, 3]
    return mesh_from_arrays(name, world, faces, props, uvs=uvs)


def _pattern_texture(display: DisplaySpec, channel: int) -> dict:
    import mitsuba as mi  # noqa: PLC0415

    pattern = display.pattern_image()[..., channel]
    # Bitmap row 0 is v = 0, the bottom of the emitting surface; the pattern's row 0 is the top.
    data = np.ascontiguousarray(np.flipud(pattern)[..., None], dtype=np.float32) * (2.0 * display.radiance)
    return {"type": "bitmap", "data": mi.TensorXf(data), "raw": True, "filter_type": "nearest", "wrap_mode": "clamp"}


def _emitter_to_world(display: DisplaySpec, rect: tuple[float, float, float, float]) -> NDArray:
    x0, x1, y0, y1 = rect
    local = np.eye(4)
    local[0, 0], local[1, 1] = (x1 - x0) / 2, (y1 - y0) / 2
    local[0, 3], local[1, 3] = (x0 + x1) / 2, (y0 + y1) / 2
    return np.asarray(display.display_to_world()) @ local


def polarized_emitter_possible(display: DisplaySpec) -> bool:
    """Whether the display can be rendered as :mod:`.polarized_display` (no sheet) in mono passes.

    A flat display whose colour channels each light one full rectangle (the built-in patterns),
    partially polarized too (the emitter scales S1, S2); curved displays and pattern images keep the sheet.
    """
    return (
        display.curvature_radius is None
        and display.pattern in BUILTIN_RECTANGLE_PATTERNS
        and all(display.lit_rectangle(c, uniform=True) is not None for c in range(3))
    )


def display_shapes(
    display: DisplaySpec, channel: int | None, *, polarized_emitter: bool = False, radiance: dict | None = None
) -> dict[str, Any]:
    """The emitting display surface and its polarizer sheet, for one colour channel.

    With ``polarized_emitter`` (only where :func:`polarized_emitter_possible`) the lit rectangle
    carries :mod:`.polarized_display`'s emitter instead, and there is no sheet.

    On a flat display whose channel lights one rectangle (the built-in patterns), only that
    rectangle emits, with constant radiance (no texture lookups, and a parameter update switches
    channels). Otherwise the whole surface emits the pattern as a bitmap, which Mitsuba's area
    emitter importance-samples by radiance, so dark parts are not sampled either way. A curved
    display is a strip mesh (:func:`curved_strip`).

    Convention: Mitsuba's ``polarizer`` angle ``theta`` turns clockwise as seen from the front
    of the sheet (``theta = 45`` transmits along display ``-X + Y``), while the rig's
    ``polarization_angle`` turns from ``+X`` toward ``+Y`` as seen from the front, so
    ``theta = -degrees(polarization_angle)``. 90 degrees gives vertically polarized light in the
    camera frame (s1 < 0) and 45 degrees gives s2 < 0 after a mirror facing the camera (tested).

    Args:
        display: display part of the rig.
        channel: colour channel 0, 1, 2 whose part of the pattern emits; None with ``radiance``.
        polarized_emitter: the lit rectangle as :mod:`.polarized_display`'s emitter, no sheet.
        radiance: emitter radiance of the whole active area instead of a channel's pattern (the
            spectral variants' texture, :func:`.spectral.display_radiance`), doubled for the sheet.

    Returns:
        ``{"display": shape, "display_polarizer": shape}`` (no sheet with ``polarized_emitter``).
    """
    for name, nominal in (("degree_of_polarization", 1.0), ("emission_exponent", 0.0)):
        if getattr(display, name) != nominal and not polarized_emitter:
            raise NotImplementedError(
                f"display.{name} {getattr(display, name):g} (nominal {nominal:g}) is rendered only by the polarized "
                "display emitter (a flat display with a built-in pattern, mono polarized variants), not through "
                "the polarizer sheet"
            )
    if (channel is None) == (radiance is None):
        raise ValueError("display_shapes needs either a channel or a radiance, not both")
    to_world = np.asarray(display.display_to_world())
    if polarized_emitter:
        if radiance is not None or not polarized_emitter_possible(display):
            raise ValueError("the polarized display emitter needs a flat display with a built-in pattern")
        from . import polarized_display  # noqa: PLC0415

        polarized_display.register()
        rect = display.lit_rectangle(channel, uniform=True)
        absorbing = np.cross(display.normal_world(), display.polarization_direction_world())
        emitter = polarized_display.emitter_dict(
            display.radiance, absorbing, display.degree_of_polarization, display.emission_exponent
        )
        return {"display": {"type": "rectangle", "to_world": scalar_transform(_emitter_to_world(display, rect)),
                            "emitter": emitter}}  # fmt: skip
    sheet_bsdf = {"type": "polarizer", "theta": -math.degrees(display.polarization_angle)}

    def whole_surface() -> dict:  # the emitter of the whole active area
        return {"type": "area", "radiance": radiance if radiance is not None else _pattern_texture(display, channel)}

    if display.curvature_radius is None:
        scale = np.diag([display.width / 2, display.height / 2, 1.0, 1.0])
        shift = np.eye(4)
        shift[2, 3] = SHEET_OFFSET
        rect = None
        if radiance is None and display.pattern in BUILTIN_RECTANGLE_PATTERNS:
            rect = display.lit_rectangle(channel, uniform=True)
        if rect is not None:
            emitting = {"type": "rectangle", "to_world": scalar_transform(_emitter_to_world(display, rect)),
                        "emitter": {"type": "area", "radiance": 2.0 * display.radiance}}  # fmt: skip
        else:
            emitting = {"type": "rectangle", "to_world": scalar_transform(to_world @ scale), "emitter": whole_surface()}
        return {
            "display": emitting,
            "display_polarizer": {"type": "rectangle", "to_world": scalar_transform(to_world @ shift @ scale),
                                  "bsdf": sheet_bsdf},
        }  # fmt: skip
    import mitsuba as mi  # noqa: PLC0415

    emitter = whole_surface()
    v, f, uv = curved_strip(display, 0.0)
    vs, fs, uvs = curved_strip(display, SHEET_OFFSET)
    # The strip's front faces +Z (toward the viewer) with counter-clockwise faces seen from +Z.
    return {
        "display": _strip_mesh("display", v, f, uv, to_world, {"emitter": mi.load_dict(emitter)}),
        "display_polarizer": _strip_mesh("display_polarizer", vs, fs, uvs, to_world,
                                         {"bsdf": mi.load_dict(sheet_bsdf)}),
    }  # fmt: skip


def display_updates(display: DisplaySpec, channel: int, params: Any) -> dict[str, Any] | None:
    """Scene-parameter updates that switch the display to ``channel``; None if a reload is needed."""
    if display.curvature_radius is not None:
        return None
    if "display.emitter.radiance.data" in params:
        return {"display.emitter.radiance.data": _pattern_texture(display, channel)["data"]}
    rect = display.lit_rectangle(channel, uniform=True)
    if rect is None or "display.to_world" not in params:
        return None
    return {"display.to_world": scalar_transform(_emitter_to_world(display, rect))}


def sensor_dict(camera: CameraSpec, window: CropWindow, spp: int, *, sampler: str = "independent") -> dict:
    """Perspective sensor for the crop window; box filter so AOVs stay per-pixel averages.

    The film is only the crop (``window.size``): the crop's field of view and its offset from
    the optical axis (``principal_point_offset_x/y``, in film widths and heights) place it in the
    virtual film. These are JIT parameters, whereas a film's size and crop are compiled into
    Dr.Jit's kernels as constants: with this form, samples whose objects project to different
    windows reuse one compiled kernel (the same pixel rays as a cropped film, to float rounding;
    tested).
    """
    c2w = np.asarray(camera.camera_to_world(), dtype=np.float64)
    origin = c2w[:3, 3]
    forward = -c2w[:3, 2]  # OpenGL camera looks along -z
    up = c2w[:3, 1]
    import mitsuba as mi  # noqa: PLC0415

    w, h = window.size
    focal_px = camera.focal_length / (camera.pixel_pitch * window.binning)
    return {
        "type": "perspective",
        "fov": math.degrees(2 * math.atan(w / (2 * focal_px))),
        "fov_axis": "x",
        "principal_point_offset_x": (window.offset[0] + w / 2 - window.film_size[0] / 2) / w,
        "principal_point_offset_y": (window.offset[1] + h / 2 - window.film_size[1] / 2) / h,
        "to_world": mi.ScalarTransform4f().look_at(origin=origin.tolist(), target=(origin + forward).tolist(),
                                                   up=up.tolist()),
        "film": {"type": "hdrfilm", "width": w, "height": h, "pixel_format": "luminance", "rfilter": {"type": "box"}},
        "sampler": {"type": sampler, "sample_count": spp},
    }  # fmt: skip


def bsdf_dict(material: MaterialSpec, channel: int | None, *, spectrum: Any = None, linear_light: bool = False) -> dict:
    """Polarization-aware Mitsuba BSDF of a material's constants, for one colour channel or spectral.

    Textures are :mod:`.textured_bsdf`'s (the mono passes of :mod:`.render`).

    Args:
        material: the material spec.
        channel: colour channel 0, 1, 2 (mono passes: scalar values at that channel), or None for
            spectral variants, where per-channel values become spectra through ``spectrum``.
        spectrum: ``spectrum(values_rgb, kind)`` -> Mitsuba spectrum for ``kind`` ``"reflectance"``
            or ``"ior"`` (required when ``channel`` is None).
        linear_light: all light reaching the material has ``S3 = 0`` (direct light from the
            display, the ``direct`` integrator): a table BSDF skips its Mueller matrix's last column.
    """

    def value(rgb: tuple[float, float, float], kind: str) -> Any:
        return float(rgb[channel]) if channel is not None else spectrum(rgb, kind)

    alpha = max(material.roughness**2, MIN_ALPHA)
    if material.kind == "pplastic":
        return {
            "type": "pplastic",
            "diffuse_reflectance": value(material.albedo, "reflectance"),
            "specular_reflectance": 1.0,
            "int_ior": float(material.ior),
            "ext_ior": 1.0,
            "alpha": alpha,
            "distribution": "ggx",
        }
    if material.kind == "conductor":
        return {
            "type": "roughconductor",
            "eta": value(material.eta, "ior"),
            "k": value(material.k, "ior"),
            "alpha": alpha,
            "distribution": "ggx",
        }
    if material.kind == "diffuse":  # Lambertian, depolarizing
        return {"type": "diffuse", "reflectance": value(material.albedo, "reflectance")}
    if material.kind == "measured":
        if channel is not None and _table_bsdf(material):
            from . import table_bsdf  # noqa: PLC0415

            table_bsdf.register()
            return {
                "type": table_bsdf.PLUGIN,
                "filename": str(material.table),
                "wavelength": CHANNEL_WAVELENGTHS_NM[channel],
                "alpha_sample": max(alpha, ALPHA_SAMPLE_LEVELS[0]),
                "linear_light": bool(linear_light),
            }
        out = {"type": "measured_polarized", "filename": str(material.table), "alpha_sample": alpha_sample(alpha)}
        if channel is not None:
            out["wavelength"] = CHANNEL_WAVELENGTHS_NM[channel]
        return out
    raise ValueError(f"unknown material kind {material.kind!r}; valid: pplastic, conductor, measured, diffuse")


def alpha_sample(alpha: float) -> float:
    """The ``alpha_sample`` of a table material: ``alpha`` rounded to :data:`ALPHA_SAMPLE_LEVELS` in log scale.

    >>> alpha_sample(0.3), alpha_sample(0.0), alpha_sample(1.0)
    (0.4, 0.05, 0.8)
    """
    levels = np.asarray(ALPHA_SAMPLE_LEVELS)
    return float(levels[np.argmin(np.abs(np.log(levels) - math.log(max(alpha, levels[0]))))])


def is_convex(vertices: NDArray, faces: NDArray) -> bool:
    """Whether a mesh is closed and convex.

    Closed: every edge (after merging coincident vertices) joins exactly two faces. Convex: the
    enclosed volume (consistent winding assumed) over the convex hull's exceeds
    :data:`CONVEX_VOLUME_RATIO`.

    >>> tet = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    >>> faces = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> is_convex(tet, faces), is_convex(tet, faces[1:])
    (True, False)
    """
    from scipy.spatial import ConvexHull, QhullError  # noqa: PLC0415

    v = np.asarray(vertices, dtype=np.float64)
    _, ids = np.unique(v, axis=0, return_inverse=True)
    f = ids.reshape(-1)[np.asarray(faces, dtype=np.int64)]
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key = edges.min(axis=1) * (int(ids.max()) + 1) + edges.max(axis=1)
    if len(f) < 4 or np.any(np.unique(key, return_counts=True)[1] != 2):
        return False  # open or non-manifold
    tri = v[np.asarray(faces, dtype=np.int64)]
    volume = abs(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum()) / 6.0
    try:
        hull = ConvexHull(v).volume
    except (QhullError, ValueError):  # flat or degenerate point sets
        return False
    return bool(hull > 0 and volume / hull > CONVEX_VOLUME_RATIO)


def auto_max_depth(meshes: list, integrator: str = "volpath", *, sheet: bool = True) -> int:
    """The path length limit a scene needs: direct light only where no object can see another or itself.

    That is one closed convex object (:func:`is_convex`); otherwise one interreflection.
    Rendering a sphere with direct light only gives the same Stokes images as with one
    interreflection, within noise, and a torus does not (tested).

    Args:
        meshes: ``(vertices, faces, ...)`` per object (:func:`.passes.world_meshes`).
        integrator: ``"volpath"`` or ``"path"`` (:data:`DIRECT_LIGHT_DEPTH`).
        sheet: whether the display has its polarizer sheet (else :mod:`.polarized_display`).
    """
    direct = DIRECT_LIGHT_DEPTH[integrator] if sheet else DIRECT_LIGHT_DEPTH["volpath"]
    if len(meshes) == 1 and is_convex(meshes[0][0], meshes[0][1]):
        return direct
    return direct + 1


def _table_bsdf(material: MaterialSpec) -> bool:
    """Whether a mono pass renders this table material with :mod:`.table_bsdf` (else ``measured_polarized``).

    In the ``*_mono_polarized`` JIT variants, for tables on uniform angle grids.
    """
    import mitsuba as mi  # noqa: PLC0415

    from . import table_bsdf  # noqa: PLC0415
    from .mono_plugins import is_mono_jit  # noqa: PLC0415

    return is_mono_jit(mi.variant() or "") and table_bsdf.uniform_axes(material.table)


def channel_updates(
    name: str, material: MaterialSpec, channel: int, *, two_sided: bool = False
) -> dict[str, Any] | None:
    """Scene-parameter updates that switch an object's BSDF to ``channel``; None if a reload is needed.

    ``two_sided``: the BSDF is wrapped in ``twosided`` (:func:`mesh_object`), one level deeper.
    Table materials rendered with :mod:`.table_bsdf` switch by replacing its data.
    """
    bsdf = f"{name}.bsdf.brdf_0" if two_sided else f"{name}.bsdf"
    if material.kind == "pplastic":
        return {f"{bsdf}.diffuse_reflectance.value": float(material.albedo[channel])}
    if material.kind == "conductor":
        return {
            f"{bsdf}.eta.value": float(material.eta[channel]),
            f"{bsdf}.k.value": float(material.k[channel]),
        }
    if material.kind == "diffuse":
        return {f"{bsdf}.reflectance.value": float(material.albedo[channel])}
    if material.kind == "measured" and _table_bsdf(material):
        import mitsuba as mi  # noqa: PLC0415

        from . import table_bsdf  # noqa: PLC0415

        data, _ = table_bsdf.channel_matrices(material.table, CHANNEL_WAVELENGTHS_NM[channel])
        return {f"{bsdf}.data": mi.Float(data.reshape(-1))}
    return None


def mesh_object(
    name: str, vertices_world: NDArray, faces: NDArray, normals_world: NDArray | None, bsdf: dict,
    *, two_sided: bool = False, uvs: NDArray | None = None,
):  # fmt: skip
    """A Mitsuba mesh built from arrays (no temporary files) carrying ``bsdf``, with OpenGL ``uvs`` if given.

    ``two_sided`` wraps the BSDF in Mitsuba's ``twosided`` (it keeps polarization): an open mesh
    seen from the back is then shaded like its front instead of black.
    """
    import mitsuba as mi  # noqa: PLC0415

    if two_sided:
        bsdf = {"type": "twosided", "bsdf": bsdf}
    return mesh_from_arrays(name, vertices_world, faces, {"bsdf": mi.load_dict(bsdf)}, normals=normals_world, uvs=uvs)


def integrator_dict(integrator: str, max_depth: int, *, aovs: bool = True) -> dict:
    """The ``stokes`` integrator around ``integrator``, with the ground-truth AOVs (:data:`AOVS`) or without.

    ``direct`` is direct light only (``max_depth`` unused), one emitter and one BSDF sample per
    camera sample as ``path`` at depth 2, with less per-path bookkeeping. More emitter samples per
    camera sample were tried and left out: they trade BSDF samples for light samples, which a
    glossy metal pays for (docs/measurements/headless.md).
    """
    inner: dict = {"type": integrator, "max_depth": max_depth}
    if integrator == "direct":
        inner = {"type": "direct"}
    if aovs:
        inner = {"type": "aov", "aovs": AOVS, "integrator": inner}
    return {"type": "stokes", "nested": inner}


def scene_dict(
    display: DisplaySpec,
    camera: CameraSpec,
    window: CropWindow,
    objects: dict[str, Any],
    channel: int | None,
    *,
    spp: int,
    max_depth: int = 4,
    integrator: str = "volpath",
    sampler: str = "independent",
    aovs: bool = True,
    polarized_emitter: bool = False,
    display_radiance: dict | None = None,
) -> dict:
    """The full Mitsuba scene dict for one colour channel (or all, spectral).

    The ``stokes`` integrator around ``integrator`` (:func:`integrator_dict`), the sensor of the crop
    window, the display (:func:`display_shapes`) and the objects.

    Args:
        display: display part of the rig.
        camera: camera part of the rig.
        window: crop window to render.
        objects: name -> Mitsuba shape (from :func:`mesh_object`) or shape dict.
        channel: colour channel 0, 1, 2 (R, G, B); None with ``display_radiance``.
        spp: samples per pixel.
        max_depth: path length limit (:data:`DIRECT_LIGHT_DEPTH` is direct light only; one more adds
            one interreflection; :func:`auto_max_depth` chooses).
        integrator: ``"volpath"`` (default; the only one whose shadow rays pass the sheet),
            ``"path"``, or ``"direct"`` (direct light only, without the sheet:
            ``polarized_emitter``); :meth:`.passes.RenderSettings.integrator_for` chooses.
        sampler: Mitsuba sampler plugin name.
        aovs: add the ground-truth AOVs (:data:`AOVS`).
        polarized_emitter: the display as :mod:`.polarized_display` without the sheet.
        display_radiance: the whole display emits this radiance (spectral variants,
            :func:`.spectral.display_radiance`) instead of channel ``channel``'s pattern.
    """
    scene = {
        "type": "scene",
        "integrator": integrator_dict(integrator, max_depth, aovs=aovs),
        "sensor": sensor_dict(camera, window, spp, sampler=sampler),
        **display_shapes(display, channel, polarized_emitter=polarized_emitter, radiance=display_radiance),
    }
    for name, obj in objects.items():
        if name in scene:
            raise ValueError(f"object name {name!r} clashes with a rig element")
        scene[name] = obj
    return scene
