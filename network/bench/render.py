"""Benchmark ``render``: error of the rendered nine maps against time, default vs naive configuration.

One blob of rough plastic 0.7 m in front of the display (the caller's scene, e.g.
``blender_addon.core.scenegen.benchmark_scene``) is rendered by the caller's renderer module
(e.g. ``blender_addon.core.render``; ``network`` never imports the scene side) at a few sample
counts in two configurations:
the default (mono-polarized pass per colour channel, ``volpath`` with next-event estimation
through the polarizer sheet, ``multijitter``, only the crop window) and a naive one (``path``,
``independent``, the full frame). Each point is timed under :mod:`network.bench.timing` and
compared with a high-spp reference (chunks of 64 spp with distinct seeds, averaged): relative
RMSE of the unpol and LP maps, RMSE of CP, mean normal error. With error ~ a / sqrt(spp) and
seconds ~ b * spp, each configuration's time to 2 % error is extrapolated; their ratio is the
speed-up of the default.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from network.bench.timing import RULE, machine, time_call
from network.metrics import normal_angle_deg
from pbrdf.sensor import decode

__all__ = ["run"]

#: Relative unpol/LP RMSE at which the configurations are compared.
TARGET_ERROR = 0.02


def _render_avg(render, spec, settings, spp: int, chunk: int):
    """Render ``spp`` samples as passes of at most ``chunk`` (bounded memory, distinct seeds), averaged."""
    acc, res, n = None, None, 0
    for k in range(0, spp, chunk):
        part = min(chunk, spp - k)
        s = dataclasses.replace(spec, seed=spec.seed + 1000 + k)
        res = render.render_stokes(s, dataclasses.replace(settings, spp=part))
        acc = res.stokes * part if acc is None else acc + res.stokes * part
        n += part
    res.stokes = acc / n
    return res


def _maps(stokes: np.ndarray) -> np.ndarray:
    """Nine maps of rendered ``(..., 3, 4)`` Stokes images."""
    return decode.nine_maps(stokes[..., [0, 1, 3]], eps=1e-3)


def run(
    render,
    spec,
    *,
    resolution: int = 384,
    ref_spp: int = 1024,
    spp: tuple[int, ...] = (4, 8, 16, 32, 64),
    repeat: int = 1,
    warmup: int = 1,
    seed: int = 0,
) -> dict:
    """Run the benchmark.

    Args:
        render: the renderer module (``render_stokes``, ``RenderSettings``, ``choose_variant``;
            ``blender_addon.core.render``).
        spec: the scene spec to render (``blender_addon.core.scenegen.benchmark_scene``).
        resolution: crop size in pixels.
        ref_spp: samples per pixel of the reference.
        spp: sample counts to time, ascending.
        repeat: timed renders per point.
        warmup: untimed renders per point before them (the first includes Dr.Jit's compilation).
        seed: point ``spp`` renders with seed ``seed + spp``.

    Returns:
        The JSON-ready result: per configuration ``points`` (``spp``, timing keys, ``seconds`` =
        the median, ``rel_rmse_unpol_lp``, ``rmse_cp``, ``normal_error_deg``,
        ``msamples_per_second``), ``first_call_seconds_incl_jit``, ``spp_for_2pct`` and
        ``seconds_for_2pct``; ``speedup_default_over_naive_at_2pct``, ``reference``,
        ``timing_rule`` and ``machine``.
    """
    spec = dataclasses.replace(spec, seed=seed)
    base = render.RenderSettings(resolution=resolution, spp=1)
    result: dict = {
        "benchmark": "render",
        "resolution": resolution,
        "reference_spp": ref_spp,
        "variant": render.choose_variant(),
        "scene": "blob, pplastic albedo (0.6, 0.4, 0.2), roughness 0.3, 0.7 m",
        "timing_rule": RULE,
    }
    ref_timing, ref = time_call(
        lambda: _render_avg(render, spec, base, ref_spp, 64),
        f"reference: {ref_spp} spp in chunks of 64 with distinct seeds, averaged (one call, not a benchmark point)",
        repeat=1,
        warmup=0,
    )
    result["reference"] = ref_timing.to_dict()
    result["reference_seconds"] = ref_timing.median
    mask = ref.mask
    ref_maps = _maps(ref.stokes)[mask]
    ref_norm = np.sqrt(np.mean(ref_maps[..., :6] ** 2))
    off = ref.window.offset
    configs = {
        "default (mono per channel, volpath, multijitter, crop)": base,
        "naive (mono per channel, path, independent, full frame)": dataclasses.replace(
            base, integrator="path", sampler="independent", crop=False
        ),
    }
    for name, settings in configs.items():
        entry: dict = {"points": []}
        for n_spp in spp:
            point_spec = dataclasses.replace(spec, seed=seed + n_spp)
            point_settings = dataclasses.replace(settings, spp=n_spp)
            timing, res = time_call(
                lambda s=point_spec, st=point_settings: render.render_stokes(s, st),
                f"render_stokes, {name}, {resolution} px, {n_spp} spp",
                repeat=repeat,
                warmup=warmup,
            )
            if not entry["points"] and timing.warmup:
                entry["first_call_seconds_incl_jit"] = timing.warmup[0]
            stokes = res.stokes
            if not settings.crop:  # the crop window's pixels inside the full film
                stokes = stokes[off[1] : off[1] + mask.shape[0], off[0] : off[0] + mask.shape[1]]
            maps = _maps(stokes)[mask]
            # Relative RMSE of unpol and LP (CP is a ratio with its own scale: reported apart).
            rel = float(np.sqrt(np.mean((maps[..., :6] - ref_maps[..., :6]) ** 2)) / ref_norm)
            cp_rmse = float(np.sqrt(np.mean((maps[..., 6:] - ref_maps[..., 6:]) ** 2)))
            normal_deg = None
            if settings.crop:
                normal_deg = float(normal_angle_deg(res.normal[mask], ref.normal[mask]).mean())
            samples = res.stokes.shape[0] * res.stokes.shape[1]
            entry["points"].append({
                "spp": n_spp, **timing.to_dict(), "seconds": timing.median, "rel_rmse_unpol_lp": rel,
                "rmse_cp": cp_rmse, "normal_error_deg": normal_deg,
                "msamples_per_second": 3 * samples * n_spp / timing.median / 1e6,
            })  # fmt: skip
        # err ~ a / sqrt(spp), seconds ~ b * spp: extrapolate the time to the target error.
        pts = entry["points"]
        a = np.median([p["rel_rmse_unpol_lp"] * np.sqrt(p["spp"]) for p in pts])
        b = np.median([p["seconds"] / p["spp"] for p in pts])
        entry["spp_for_2pct"] = float((a / TARGET_ERROR) ** 2)
        entry["seconds_for_2pct"] = float(b * (a / TARGET_ERROR) ** 2)
        result[name] = entry
    names = list(configs)
    result["speedup_default_over_naive_at_2pct"] = (
        result[names[1]]["seconds_for_2pct"] / result[names[0]]["seconds_for_2pct"]
    )
    result["machine"] = machine()
    return result
