"""Benchmark ``decode``: a raw HDR bracket decoded into the nine maps, against polanalyser.

A 2448 x 2048 IMX250MYR raw bracket (four exposures, with noise) of a smooth scene whose exact
Stokes images are known is decoded by :func:`pbrdf.sensor.decode.decode` on the half and full
grids, next to polanalyser 3.0's single-bracket demosaic + Stokes of the same mosaic (the
reference implementation; skipped with a note when it is not installed). Reported per route:
the timing (:mod:`network.bench.timing`), peak traced memory in a separate run
(:func:`network.bench.memory.traced_peak_mib`), the output shape and the Stokes error on a
noise-free, unquantised version of the scene (pure interpolation error), plus the speed ratios.

Example:
    >>> s = smooth_stokes_scene(4, 6)
    >>> s.shape
    (4, 6, 3, 4)
"""

from __future__ import annotations

import numpy as np

from network.bench.memory import traced_peak_mib
from network.bench.timing import RULE, machine, time_call
from pbrdf.polar import stokes as pstokes
from pbrdf.sensor import camera, decode

__all__ = ["run", "smooth_stokes_scene"]

#: Pixels left out at each border when comparing with the truth (the demosaic's support).
MARGIN = 8


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


def run(*, height: int = 2048, width: int = 2448, repeat: int = 5, warmup: int = 1, seed: int = 0) -> dict:
    """Run the benchmark.

    Args:
        height: raw height in pixels, a multiple of 4, >= 32.
        width: raw width in pixels, a multiple of 4, >= 32.
        repeat: timed calls per route.
        warmup: untimed calls per route before them.
        seed: seed of the camera noise.

    Returns:
        The JSON-ready result: ``ours_half`` and ``ours_full`` (timing keys, ``peak_mib``,
        ``output_shape``, ``stokes_max_abs_error_noise_free``), ``polanalyser`` (the same, or
        ``skipped``), the speed ratios, ``timing_rule`` and ``machine``.

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
    result: dict = {"benchmark": "decode", "height": h, "width": w, "brackets": len(model.exposures),
                    "timing_rule": RULE}  # fmt: skip

    # Float-exactness on a noise-free float mosaic (no quantisation): pure interpolation error.
    exact_model = model.replace(
        exposures=(1.0,), sensor=camera.SensorParams(black_level=0.0, bits=16, electrons_per_unit=1 / 0.38)
    )
    mosaic = camera.mosaic(truth, exact_model).astype(np.float32)
    ref3 = truth[..., [0, 1, 3]]

    for grid in ("half", "full"):
        timing, _ = time_call(
            lambda g=grid: decode.decode(raws, model, grid=g),
            f"pbrdf.sensor.decode.decode of a {len(model.exposures)}-exposure {h}x{w} uint16 bracket, grid={grid!r}",
            repeat=repeat,
            warmup=warmup,
        )
        peak = traced_peak_mib(lambda g=grid: decode.decode(raws, model, grid=g))
        dec = decode.decode(mosaic[None], exact_model, grid=grid)
        if grid == "half":
            ref = ref3.reshape(h // 2, 2, w // 2, 2, 3, 3).mean(axis=(1, 3))
            m = MARGIN // 2
        else:
            ref, m = ref3, MARGIN
        err = np.abs(dec.stokes - ref)[m:-m, m:-m].max()
        result[f"ours_{grid}"] = {
            **timing.to_dict(),
            "peak_mib": peak,
            "peak_memory": "tracemalloc peak of one separate call",
            "output_shape": list(dec.maps.shape),
            "stokes_max_abs_error_noise_free": float(err),
        }
    result["polanalyser"] = _polanalyser(raws, mosaic, ref3, repeat=repeat, warmup=warmup)
    if "seconds_median" in result["polanalyser"]:
        med = result["polanalyser"]["seconds_median"]
        for grid in ("half", "full"):
            result[f"speed_ratio_polanalyser_1_bracket_over_ours_4_brackets_{grid}"] = (
                med / result[f"ours_{grid}"]["seconds_median"]
            )
    result["machine"] = machine(numpy=np.__version__)
    return result


def _polanalyser(raws: np.ndarray, mosaic: np.ndarray, ref3: np.ndarray, *, repeat: int, warmup: int) -> dict:
    """The polanalyser route on the longest exposure: timing, memory and noise-free error (or ``skipped``)."""
    try:
        import polanalyser as pa  # noqa: PLC0415
    except Exception as exc:  # noqa: BLE001 - report any import failure in the JSON
        return {"skipped": f"polanalyser unavailable: {exc}"}
    angles = np.deg2rad([0, 45, 90, 135])
    raw0 = raws[-1]

    def pa_route(raw=raw0):
        imgs = pa.demosaicing(raw, pa.COLOR_PolarRGB)
        return pa.calcStokes(imgs, angles)

    h, w = raw0.shape
    timing, _ = time_call(
        pa_route,
        f"polanalyser demosaicing(COLOR_PolarRGB) + calcStokes of one {h}x{w} uint16 exposure",
        repeat=repeat,
        warmup=warmup,
    )
    peak = traced_peak_mib(pa_route)
    # Its error on the same noise-free scene, scaled to 16 bit (its input must be integer).
    scale = 65535.0 / mosaic.max()
    st = pa.calcStokes(pa.demosaicing(np.rint(mosaic * scale).astype(np.uint16), pa.COLOR_PolarRGB), angles)
    st = st[..., ::-1, :] / scale  # BGR -> RGB
    pa3 = np.stack([st[..., 0], st[..., 1], st[..., 2]], axis=-1)  # its s2 channel is our s3
    err = np.abs(pa3 - ref3)[MARGIN:-MARGIN, MARGIN:-MARGIN].max()
    return {
        "version": getattr(pa, "__version__", "3.0.0"),
        "route": "demosaicing(COLOR_PolarRGB) + calcStokes, one bracket",
        **timing.to_dict(),
        "peak_mib": peak,
        "peak_memory": "tracemalloc peak of one separate call",
        "stokes_max_abs_error_noise_free_16bit": float(err),
    }
