"""Benchmark ``decode``: a raw HDR bracket decoded into the nine maps, against polanalyser.

A 2448 x 2048 IMX250MYR raw bracket (four exposures, with noise) of a smooth scene whose exact
Stokes images are known is decoded by :func:`pbrdf.sensor.decode.decode` on the half and full
grids, next to polanalyser 3.0's single-bracket demosaic + Stokes of the same mosaic (the
reference implementation; skipped with a note when it is not installed). A second bracket of
the same scene, brighter (:func:`saturated_scene`: the longest exposure saturates 30 % of the
2x2 blocks, a specular highlight every exposure), is decoded on the full grid too: the path
where exposures are dropped per block and pixels are masked. Reported per route: the timing
(:mod:`network.bench.timing`; the routes' timed calls alternate, so that a change of the
machine's load hits them alike), peak traced memory in a separate run
(:func:`network.bench.memory.traced_peak_mib`), the output shape and the Stokes error on a
noise-free, unquantised version of the scene (pure interpolation error), plus the speed ratios
and ``meets_target``: our full grid on four brackets, plain and saturated, not slower than
polanalyser on one.

Example:
    >>> s = smooth_stokes_scene(4, 6)
    >>> s.shape
    (4, 6, 3, 4)
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from network.bench.memory import traced_peak_mib
from network.bench.timing import RULE, Timing, machine, time_interleaved
from pbrdf.polar import stokes as pstokes
from pbrdf.sensor import camera, decode

__all__ = ["run", "saturated_scene", "smooth_stokes_scene"]

#: Pixels left out at each border when comparing with the truth (the demosaic's support).
MARGIN = 8
#: Fraction of the 2x2 blocks that the longest exposure saturates in :func:`saturated_scene`.
SATURATED_FRACTION = 0.3
#: The target: each of these routes at least as fast as polanalyser's one bracket.
TARGET_ROUTES = ("ours_full", "ours_full_saturated")


def smooth_stokes_scene(h: int, w: int) -> np.ndarray:
    """Smooth, fully known Stokes images: an affine-in-space mix of states per colour.

    Args:
        h: height in pixels.
        w: width in pixels.

    Returns:
        ``(H, W, 3, 4)`` float64 physical Stokes vectors (s0 between 0.05 and about 1).
    """
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    u, v = yy / h, xx / w
    s = np.empty((h, w, 3, 4))
    for c in range(3):
        s0 = 0.05 + 0.5 * u + 0.2 * v + 0.1 * c
        s[..., c, :] = pstokes.stokes(s0, 0.2 + 0.5 * v, 0.3 + c + 0.5 * u, 0.1 * (c - 1) * u)
    return s


def saturated_scene(truth: np.ndarray, model: camera.CameraModel, fraction: float = SATURATED_FRACTION) -> np.ndarray:
    """``truth`` brightened so that the longest exposure saturates ``fraction`` of the 2x2 blocks.

    On top, a disc of display light (vertically polarized, a specular highlight; radius 5 % of
    the shorter side, at the centre) bright enough to saturate every exposure: those blocks are
    unmeasured and masked.

    Args:
        truth: ``(H, W, 3, 4)`` Stokes images, H and W multiples of 4.
        model: the camera model whose exposures and sensor decide the saturation.
        fraction: fraction of the blocks above the saturation threshold in the longest exposure
            (noise-free).

    Returns:
        ``(H, W, 3, 4)`` float64 Stokes images.
    """
    h, w = truth.shape[:2]
    sensor = model.sensor
    threshold = sensor.saturation * sensor.white_level - sensor.black_level  # black-subtracted DN
    block_max = _block_max(camera.mosaic(truth, model)[None])[0]
    gain = threshold / (sensor.dn_per_unit_second * max(model.exposures) * np.quantile(block_max, 1.0 - fraction))
    scene = truth * gain
    yy, xx = np.mgrid[0:h, 0:w]
    disc = (yy - h / 2) ** 2 + (xx - w / 2) ** 2 < (0.05 * min(h, w)) ** 2
    level = 4.0 * threshold / (sensor.dn_per_unit_second * min(model.exposures))
    scene[disc] += level * np.array([1.0, -1.0, 0.0, 0.0])
    return scene


def _block_max(raws: np.ndarray) -> np.ndarray:
    """``(E, H, W)`` -> ``(E, H/2, W/2)``: the maximum of each 2x2 block."""
    pairs = np.maximum(raws[:, 0::2], raws[:, 1::2])
    return np.maximum(pairs[..., 0::2], pairs[..., 1::2])


def _saturated_fractions(raws: np.ndarray, sensor: camera.SensorParams) -> list[float]:
    """Per exposure, the fraction of 2x2 blocks with a pixel at or above the saturation threshold."""
    blocks = _block_max(raws) >= sensor.saturation * sensor.white_level
    return [float(b.mean()) for b in blocks]


def run(*, height: int = 2048, width: int = 2448, repeat: int = 5, warmup: int = 1, seed: int = 0) -> dict:
    """Run the benchmark.

    Args:
        height: raw height in pixels, a multiple of 4, >= 32.
        width: raw width in pixels, a multiple of 4, >= 32.
        repeat: timed calls per route.
        warmup: untimed calls per route before them.
        seed: seed of the camera noise.

    Returns:
        The JSON-ready result: ``ours_half``, ``ours_full`` and ``ours_full_saturated`` (timing
        keys, ``peak_mib``, ``output_shape``; the first two ``stokes_max_abs_error_noise_free``,
        the last ``saturated_fraction_per_exposure`` and ``masked_fraction``), ``polanalyser``
        (the same, or ``skipped``), the speed ratios, ``target`` and ``meets_target`` (None
        without polanalyser), ``timing_rule``, ``timing_order`` and ``machine``.

    Raises:
        ValueError: bad sizes.
    """
    h, w = height, width
    if h % 4 or w % 4 or min(h, w) < 32:
        raise ValueError(f"height and width must be multiples of 4 and at least 32, got {h} x {w}")
    model = camera.CameraModel()
    rng = np.random.default_rng(seed)
    truth = smooth_stokes_scene(h, w)
    raws = camera.simulate_capture(truth, model, rng=rng, noise=True)
    raws_sat = camera.simulate_capture(saturated_scene(truth, model), model, rng=rng, noise=True)
    n = len(model.exposures)
    result: dict = {"benchmark": "decode", "height": h, "width": w, "brackets": n, "timing_rule": RULE,
                    "timing_order": "warm-up calls of every route, then the routes' timed calls in turn, "
                                    "repeat rounds"}  # fmt: skip

    what = f"pbrdf.sensor.decode.decode of a {n}-exposure {h}x{w} uint16 bracket"
    calls = {
        "ours_half": (lambda: decode.decode(raws, model, grid="half"), f"{what}, grid='half'"),
        "ours_full": (lambda: decode.decode(raws, model, grid="full"), f"{what}, grid='full'"),
        "ours_full_saturated": (
            lambda: decode.decode(raws_sat, model, grid="full"),
            f"{what} (longest exposure {SATURATED_FRACTION:.0%} saturated, a highlight saturated in all), grid='full'",
        ),
    }
    pa_route = _polanalyser_route(raws[-1])
    if isinstance(pa_route, tuple):
        calls["polanalyser"] = pa_route
    timings = {k: t for k, (t, _) in time_interleaved(calls, repeat=repeat, warmup=warmup).items()}

    # Float-exactness on a noise-free float mosaic (no quantisation): pure interpolation error.
    exact_model = model.replace(
        exposures=(1.0,), sensor=camera.SensorParams(black_level=0.0, bits=16, electrons_per_unit=1 / 0.38)
    )
    mosaic = camera.mosaic(truth, exact_model).astype(np.float32)
    ref3 = truth[..., [0, 1, 3]]
    for key in ("ours_half", "ours_full", "ours_full_saturated"):
        grid = "half" if key == "ours_half" else "full"
        entry = {**timings[key].to_dict(), "peak_mib": traced_peak_mib(calls[key][0]),
                 "peak_memory": "tracemalloc peak of one separate call"}  # fmt: skip
        if key == "ours_full_saturated":
            dec = calls[key][0]()
            entry["saturated_fraction_per_exposure"] = _saturated_fractions(raws_sat, model.sensor)
            entry["masked_fraction"] = float(1.0 - dec.mask.mean())
        else:
            dec = decode.decode(mosaic[None], exact_model, grid=grid)
            if grid == "half":
                ref = ref3.reshape(h // 2, 2, w // 2, 2, 3, 3).mean(axis=(1, 3))
                m = MARGIN // 2
            else:
                ref, m = ref3, MARGIN
            entry["stokes_max_abs_error_noise_free"] = float(np.abs(dec.stokes - ref)[m:-m, m:-m].max())
        entry["output_shape"] = list(dec.maps.shape)
        result[key] = entry
    if isinstance(pa_route, tuple):
        result["polanalyser"] = _polanalyser_entry(pa_route, timings["polanalyser"], mosaic, ref3)
    else:
        result["polanalyser"] = pa_route
    result["target"] = f"{' and '.join(TARGET_ROUTES)} ({n} brackets) not slower than polanalyser on one bracket"
    result["meets_target"] = None
    if "seconds_median" in result["polanalyser"]:
        med = result["polanalyser"]["seconds_median"]
        for key in ("ours_half", "ours_full", "ours_full_saturated"):
            suffix = key.removeprefix("ours_")
            result[f"speed_ratio_polanalyser_1_bracket_over_ours_{n}_brackets_{suffix}"] = (
                med / result[key]["seconds_median"]
            )
        result["meets_target"] = all(result[k]["seconds_median"] <= med for k in TARGET_ROUTES)
    result["machine"] = machine(numpy=np.__version__)
    return result


def _polanalyser_route(raw: np.ndarray) -> tuple[Callable[[], object], str] | dict:
    """The polanalyser route on one exposure as ``(call, what)``, or ``{"skipped": why}``."""
    try:
        import polanalyser as pa  # noqa: PLC0415
    except Exception as exc:  # noqa: BLE001 - report any import failure in the JSON
        return {"skipped": f"polanalyser unavailable: {exc}"}
    angles = np.deg2rad([0, 45, 90, 135])

    def pa_route():
        return pa.calcStokes(pa.demosaicing(raw, pa.COLOR_PolarRGB), angles)

    h, w = raw.shape
    return pa_route, f"polanalyser demosaicing(COLOR_PolarRGB) + calcStokes of one {h}x{w} uint16 exposure"


def _polanalyser_entry(route: tuple, timing: Timing, mosaic: np.ndarray, ref3: np.ndarray) -> dict:
    """The polanalyser entry: timing, memory and its error on the noise-free scene."""
    import polanalyser as pa  # noqa: PLC0415

    angles = np.deg2rad([0, 45, 90, 135])
    # Its error on the same noise-free scene, scaled to 16 bit (its input must be integer).
    scale = 65535.0 / mosaic.max()
    st = pa.calcStokes(pa.demosaicing(np.rint(mosaic * scale).astype(np.uint16), pa.COLOR_PolarRGB), angles)
    st = st[..., ::-1, :] / scale  # BGR -> RGB
    pa3 = np.stack([st[..., 0], st[..., 1], st[..., 2]], axis=-1)  # its s2 channel is our s3
    err = np.abs(pa3 - ref3)[MARGIN:-MARGIN, MARGIN:-MARGIN].max()
    return {
        "version": getattr(pa, "__version__", "3.0.0"),
        "route": "demosaicing(COLOR_PolarRGB) + calcStokes, one bracket (the longest exposure)",
        **timing.to_dict(),
        "peak_mib": traced_peak_mib(route[0]),
        "peak_memory": "tracemalloc peak of one separate call",
        "stokes_max_abs_error_noise_free_16bit": float(err),
    }
