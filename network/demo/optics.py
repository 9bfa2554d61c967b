"""The optics/camera round trip on a built-in analytic scene (behind ``headless/optics_check.py``).

A dielectric sphere and a gold sphere sit 0.7 m in front of the camera; behind the camera the
LCD shows the RGB binary pattern with vertically polarized light. The scene is shaded
analytically (mirror-like Fresnel reflection of the display through the library's Mueller
algebra, Lambertian diffuse from each colour region of the display), then goes through the
camera model (QWP, micro-polarizers, IMX250MYR mosaic, Poisson-Gaussian noise, 12-bit HDR
brackets) and back through the decoder, exactly as a real capture would. Comparing the decoded
nine maps with the nine maps of the exact Stokes images checks the optics, the camera model and
the decoder together, without Mitsuba or a network.

Frames: metres, camera frame (x right, y up, z toward the camera; the camera looks along -z).

Example:
    >>> pattern_rgb(np.array([-0.1, 0.1]), np.array([0.1, -0.1]))  # right-and-up, left-and-down
    array([[1., 0., 1.],
           [0., 1., 0.]])
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from network.demo.report import image_grid
from pbrdf.io.atomic import atomic_open, atomic_write_text
from pbrdf.io.strict_json import dumps_strict
from pbrdf.polar import fresnel, mueller
from pbrdf.sensor import camera, decode

__all__ = [
    "DISPLAY_RADIANCE",
    "DISPLAY_SIZE",
    "DISPLAY_Z",
    "GOLD_ETA",
    "MIN_SIGNAL",
    "PLASTIC_ALBEDO",
    "PLASTIC_ETA",
    "SPHERES",
    "RoundTrip",
    "pattern_rgb",
    "render_stokes",
    "round_trip",
    "run_optics_check",
    "write_outputs",
]

DISPLAY_SIZE = (1.2096, 0.6804)  # Samsung Odyssey Ark 55" active area, metres
DISPLAY_Z = 0.05  # display plane just behind the camera, facing -z (toward the objects)
DISPLAY_RADIANCE = 1.0
# Gold optical constants (eta = n - ik) at the R, G, B wavelengths 650, 550, 450 nm
# (Johnson & Christy 1972, rounded).
GOLD_ETA = (0.166 - 3.15j, 0.43 - 2.46j, 1.44 - 1.85j)
SPHERES = (
    # centre (m), radius (m), material
    ((-0.085, 0.0, -0.70), 0.075, "plastic"),
    ((0.085, 0.0, -0.70), 0.075, "gold"),
)
PLASTIC_ALBEDO = (0.55, 0.25, 0.12)
PLASTIC_ETA = 1.5
#: Total s0 (sum of R, G, B) below which a decoded pixel counts as unlit background.
MIN_SIGNAL = 2e-3


def pattern_rgb(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Display pattern at camera-frame points on the display plane.

    Seen from the object (looking along +z) the display's right (+X) is camera -x: red lights
    the right half, green the left half, blue the upper half.

    Args:
        x: camera-frame x of the points in metres, any shape ``(...)``.
        y: camera-frame y of the points, the same shape.

    Returns:
        ``(..., 3)`` float64 in {0, 1}: which colour channels are lit (0 outside the display).
    """
    inside = (np.abs(x) <= DISPLAY_SIZE[0] / 2) & (np.abs(y) <= DISPLAY_SIZE[1] / 2)
    red = (x < 0) & inside
    green = (x >= 0) & inside
    blue = (y > 0) & inside
    return np.stack([red, green, blue], axis=-1).astype(np.float64)


def _normalize(v: np.ndarray) -> np.ndarray:
    """Unit vectors along the last axis (zero-safe)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, 1e-12)


def render_stokes(h: int, w: int, fov_deg: float = 22.0) -> dict[str, np.ndarray]:
    """Shade the analytic two-sphere scene at pixel centres.

    Args:
        h: image height in pixels.
        w: image width in pixels.
        fov_deg: horizontal field of view in degrees.

    Returns:
        ``stokes`` ``(H, W, 3, 4)`` (R, G, B; Mitsuba's camera Stokes frame), ``normal``
        ``(H, W, 3)`` (camera frame, zero on the background) and ``mask`` ``(H, W)`` bool.
    """
    f = 0.5 * w / np.tan(np.deg2rad(fov_deg) / 2)
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    d = _normalize(np.stack([(jj - w / 2) / f, -(ii - h / 2) / f, -np.ones_like(ii)], axis=-1))  # row 0 = top
    t_hit = np.full((h, w), np.inf)
    normal = np.zeros((h, w, 3))
    material = np.full((h, w), -1)
    for k, (c, r, _) in enumerate(SPHERES):
        c = np.asarray(c)
        b = d @ c
        disc = b * b - (c @ c - r * r)
        t = np.where(disc > 0, b - np.sqrt(np.maximum(disc, 0)), np.inf)
        closer = (t > 0) & (t < t_hit)
        t_hit = np.where(closer, t, t_hit)
        material = np.where(closer, k, material)
        p = d * np.where(closer, t, 0.0)[..., None]
        normal = np.where(closer[..., None], _normalize(p - c), normal)
    mask = material >= 0
    stokes = np.zeros((h, w, 3, 4))
    if not mask.any():
        return {"stokes": stokes, "normal": normal, "mask": mask}

    dv, nv = d[mask], normal[mask]
    pos = dv * t_hit[mask][:, None]
    v = -dv  # toward the camera
    cos_i = np.clip(np.sum(nv * v, axis=-1), 1e-6, 1.0)
    refl = 2 * cos_i[:, None] * nv - v  # mirror direction, toward the display
    # Where the mirror ray meets the display plane.
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (DISPLAY_Z - pos[:, 2]) / refl[:, 2]
    hit = (refl[:, 2] > 0) & np.isfinite(s)
    q = pos + refl * np.where(hit, s, 0.0)[:, None]
    emitted = pattern_rgb(q[:, 0], q[:, 1]) * hit[:, None] * DISPLAY_RADIANCE  # (P, 3)

    # Frames: the display's light travels along -refl, polarized along the display's vertical
    # axis projected across the ray, so its Stokes vector is [1, -1, 0, 0] in the frame whose
    # x-axis is perpendicular to that field.
    d_in = -refl
    e_field = _normalize(np.array([0.0, 1.0, 0.0]) - np.sum(d_in * [0, 1, 0], -1)[:, None] * d_in)
    x_in = _normalize(np.cross(e_field, d_in))
    s_axis = np.cross(d_in, nv)
    degenerate = np.linalg.norm(s_axis, axis=-1) < 1e-9  # normal incidence: any s-axis works
    s_axis = np.where(degenerate[:, None], x_in, s_axis)
    s_axis = _normalize(s_axis)
    x_cam = _normalize(np.cross(dv, np.array([0.0, 1.0, 0.0])))  # Mitsuba's stokes integrator frame
    rot_in = mueller.rotate_stokes_basis(d_in, x_in, s_axis)
    rot_out = mueller.rotate_stokes_basis(v, s_axis, x_cam)
    s_display = np.array([1.0, -1.0, 0.0, 0.0])

    mat = material[mask]
    out = np.zeros((mask.sum(), 3, 4))
    # Diffuse irradiance from each colour region of the display (quadrature over patches).
    gx, gy = np.meshgrid(
        (np.arange(32) + 0.5) / 32 * DISPLAY_SIZE[0] - DISPLAY_SIZE[0] / 2,
        (np.arange(18) + 0.5) / 18 * DISPLAY_SIZE[1] - DISPLAY_SIZE[1] / 2,
    )
    patches = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, DISPLAY_Z)], axis=-1)
    patch_area = DISPLAY_SIZE[0] * DISPLAY_SIZE[1] / gx.size
    patch_rgb = pattern_rgb(patches[:, 0], patches[:, 1]) * DISPLAY_RADIANCE
    for k, (_, _, kind) in enumerate(SPHERES):
        sel = mat == k
        if kind != "plastic" or not sel.any():
            continue
        to_patch = patches[None] - pos[sel][:, None]  # (P, K, 3)
        dist2 = np.sum(to_patch**2, -1)
        wdir = to_patch / np.sqrt(dist2)[..., None]
        cos_n = np.clip(np.sum(wdir * nv[sel][:, None], -1), 0, None)
        cos_d = np.clip(wdir[..., 2], 0, None)  # the display faces -z: cos = w . (+z)
        irr = (cos_n * cos_d / dist2) @ patch_rgb * patch_area  # (P, 3)
        # Light entering the surface loses its Fresnel reflection (unpolarized diffuse).
        trans = 1.0 - fresnel.fresnel_reflectance(cos_i[sel], PLASTIC_ETA)
        out[sel, :, 0] += np.asarray(PLASTIC_ALBEDO) / np.pi * irr * trans[:, None]
    for c in range(3):
        for k, (_, _, kind) in enumerate(SPHERES):
            sel = mat == k
            if not sel.any():
                continue
            eta_c = GOLD_ETA[c] if kind == "gold" else PLASTIC_ETA
            m_spec = rot_out[sel] @ fresnel.reflection_mueller(cos_i[sel], eta_c) @ rot_in[sel]
            out[sel, c] += emitted[sel, c, None] * (m_spec @ s_display)
    stokes[mask] = out
    return {"stokes": stokes, "normal": normal, "mask": mask}


@dataclass
class RoundTrip:
    """Everything one round trip produced (see :func:`round_trip`).

    Attributes:
        model: the camera model used.
        scene: :func:`render_stokes` at the raw resolution.
        raws: ``(E, H, W)`` uint16 raw brackets.
        decoded: the decoder's result on the half grid (``maps`` ``(H/2, W/2, 9)``, ``mask``).
        truth_maps: ``(H/2, W/2, 9)`` float32 nine maps of the exact Stokes images on the half grid.
        inner: ``(H/2, W/2)`` bool, pixels compared (decoded mask, away from silhouettes).
        metrics: per-map errors, mask agreement and seconds per stage (JSON-ready).
    """

    model: camera.CameraModel
    scene: dict[str, np.ndarray]
    raws: np.ndarray
    decoded: decode.Decoded
    truth_maps: np.ndarray
    inner: np.ndarray
    metrics: dict


def round_trip(height: int, width: int, *, seed: int = 0) -> RoundTrip:
    """Shade, capture (with noise) and decode the analytic scene; compare with the exact maps.

    Args:
        height: raw height in pixels, a multiple of 4.
        width: raw width in pixels, a multiple of 4.
        seed: seed of the camera noise.

    Returns:
        The arrays and ``metrics``: ``raw_shape``, ``decoded_shape``, ``mask_iou_vs_lit_truth``
        (decoded mask against where the truth has signal), ``maps`` (``{name: {mae, rmse,
        truth_mean}}`` over the inner pixels) and ``timings`` (seconds per stage).

    Raises:
        ValueError: sizes not multiples of 4 or below 16.
    """
    if height % 4 or width % 4 or min(height, width) < 16:
        raise ValueError(f"height and width must be multiples of 4 and at least 16, got {height} x {width}")
    from scipy import ndimage  # noqa: PLC0415

    timings: dict[str, float] = {}
    model = camera.CameraModel()
    rng = np.random.default_rng(seed)

    t0 = time.perf_counter()
    scene = render_stokes(height, width)
    half = render_stokes(height // 2, width // 2)  # ground truth on the decoder's half grid
    timings["shade_scene_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    raws = camera.simulate_capture(scene["stokes"], model, rng=rng, noise=True)
    timings["camera_model_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    dec = decode.decode(raws, model, grid="half", min_signal=MIN_SIGNAL)
    timings["decode_s"] = time.perf_counter() - t0

    truth_maps = decode.nine_maps(half["stokes"][..., [0, 1, 3]])
    # Compare away from silhouettes, where a 2x2 block mixes object and background.
    inner = ndimage.binary_erosion(half["mask"], iterations=3) & dec.mask
    err = np.abs(dec.maps - truth_maps)
    # The decoder's mask marks measured, lit pixels; compare it with where the truth has signal
    # (parts of the gold sphere that mirror no display are black and rightly unmasked).
    lit = half["stokes"][..., 0].sum(axis=-1) > MIN_SIGNAL
    metrics = {
        "raw_shape": list(raws.shape),
        "decoded_shape": list(dec.maps.shape),
        "mask_iou_vs_lit_truth": float((dec.mask & lit).sum() / max((dec.mask | lit).sum(), 1)),
        "maps": {
            name: {
                "mae": float(err[..., i][inner].mean()),
                "rmse": float(np.sqrt((err[..., i][inner] ** 2).mean())),
                "truth_mean": float(truth_maps[..., i][inner].mean()),
            }
            for i, name in enumerate(decode.NINE_MAP_NAMES)
        },
        "timings": timings,
    }
    return RoundTrip(model, scene, raws, dec, truth_maps.astype(np.float32), inner, metrics)


def _save_npy(path: Path, array: np.ndarray) -> Path:
    """Write one ``.npy`` atomically."""
    with atomic_open(path) as f:
        np.save(f, array, allow_pickle=False)
    return path


def write_outputs(out: str | Path, result: RoundTrip) -> list[Path]:
    """Write the round trip's arrays, capture folder and figures.

    Args:
        out: output folder (created if missing).
        result: from :func:`round_trip`.

    Returns:
        The written paths: ``maps.npy``, ``mask.npy``, ``truth_maps.npy``, ``capture/``,
        ``inputs.png`` and ``nine_maps.png``.
    """
    from pbrdf.data import capture  # noqa: PLC0415

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    dec, truth_maps, inner, model, raws, scene = (result.decoded, result.truth_maps, result.inner, result.model,
                                                  result.raws, result.scene)  # fmt: skip
    written = [
        _save_npy(out / "maps.npy", dec.maps),
        _save_npy(out / "mask.npy", dec.mask),
        _save_npy(out / "truth_maps.npy", truth_maps),
        capture.save_capture(out / "capture", raws, model, overwrite=True),
    ]
    height, width = raws.shape[1:]
    s0_rgb = scene["stokes"][..., 0]
    lp_rgb = -scene["stokes"][..., 1]
    scale = np.percentile(s0_rgb[scene["mask"]], 99) if scene["mask"].any() else 1.0
    white = model.sensor.white_level
    zoom = raws[-1][: height // 8, : width // 8] / white
    written.append(image_grid(
        out / "inputs.png",
        [
            [s0_rgb / scale, np.clip(lp_rgb / scale, 0, 1), scene["normal"] * 0.5 + 0.5],
            [raws[0] / white, raws[-1] / white, zoom],
        ],
        [
            ["true s0 (RGB)", "true LP = -s1 (RGB)", "normals (camera frame)"],
            [f"raw {model.exposures[0] * 1e3:.0f} ms", f"raw {model.exposures[-1] * 1e3:.0f} ms",
             "raw (zoom: 4x4 mosaic)"],
        ],
        [(0, 1)] * 3,
        ["gray"] * 3,
    ))  # fmt: skip
    names = list(decode.NINE_MAP_NAMES)
    limits, cmaps = [], []
    for i in range(9):
        vals = truth_maps[..., i][inner] if inner.any() else np.zeros(1)
        if i < 6:
            limits.append((0.0, float(np.percentile(vals, 99.5)) or 1.0))
            cmaps.append("viridis")
        else:
            lim = float(np.percentile(np.abs(vals), 99.5)) or 0.1
            limits.append((-lim, lim))
            cmaps.append("coolwarm")
    written.append(image_grid(
        out / "nine_maps.png",
        [
            [dec.maps[..., i] for i in range(9)],
            [truth_maps[..., i] for i in range(9)],
            [np.where(inner, dec.maps[..., i] - truth_maps[..., i], np.nan) for i in range(9)],
        ],
        [[f"decoded {n}" for n in names], [f"truth {n}" for n in names], [f"error {n}" for n in names]],
        [limits, limits, [(-0.1 * hi, 0.1 * hi) for _, hi in limits]],
        [cmaps, cmaps, ["coolwarm"] * 9],
    ))  # fmt: skip
    return written


def run_optics_check(
    out: str | Path, *, height: int = 384, width: int = 512, seed: int = 0, progress: bool = False
) -> dict:
    """Run the round trip and write everything to ``out``, ending with ``metrics.json``.

    Args:
        out: output folder (created if missing).
        height: raw height in pixels, a multiple of 4.
        width: raw width in pixels, a multiple of 4.
        seed: seed of the camera noise.
        progress: show a progress bar over the two stages.

    Returns:
        The metrics of :func:`round_trip`, with ``timings["write_s"]`` added.

    Raises:
        ValueError: bad sizes.
        OSError: unwritable output folder.
    """
    from tqdm import tqdm  # noqa: PLC0415

    out = Path(out)
    with tqdm(total=2, desc="optics check", unit="stage", disable=not progress) as bar:
        result = round_trip(height, width, seed=seed)
        bar.update()
        t0 = time.perf_counter()
        write_outputs(out, result)
        result.metrics["timings"]["write_s"] = time.perf_counter() - t0
        atomic_write_text(out / "metrics.json", dumps_strict(result.metrics) + "\n")
        bar.update()
    return result.metrics
