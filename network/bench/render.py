"""Benchmark ``render``: time per dataset sample to 2 % map error, default against naive configurations.

The caller passes the renderer module (e.g. ``blender_addon.core.render``; ``network`` never
imports the scene side) and one or more scenes by name, e.g. the blob of rough plastic 0.7 m in
front of the display (``blender_addon.core.scenegen.benchmark_scene``) and the same blob with a
pBRDF table material (``headless/bench.py render`` builds both). Per scene:

* a reference: the default configuration at ``ref_spp`` samples per pixel, rendered in chunks
  (distinct seeds, averaged; the chunk is the largest benchmark ``spp`` when it divides
  ``ref_spp``, so the reference reuses that point's compiled kernels);
* four configurations, each timed at a few ``spp`` under :mod:`network.bench.timing`, one
  ``render_stokes`` call (the three colour passes of one dataset sample) per timed call:
  ``default`` (the renderer's defaults: the polarized display emitter, ``direct`` where direct
  light is all and ``path`` otherwise, ``multijitter``, only the crop window, ``max_depth``
  chosen from the scene), ``sheet`` (the same with the display behind its polarizer sheet and
  ``volpath``: the previous default), ``naive_path`` (sheet, ``path``, ``independent``, the full
  frame) and ``naive_volpath`` (sheet, ``volpath``, ``independent``, the full frame).

Error: relative RMSE of the unpol and LP maps against the reference over the reference's object
pixels (CP, a ratio with its own scale, as its RMSE apart). The reference has noise of its own,
which adds to every measured error: ``err^2 = e^2(spp) + e_ref^2``. ``e_ref^2`` follows from the
default configuration at the chunk size (``e^2(chunk) = v``, ``e_ref^2 = v chunk / ref_spp``) and
is subtracted. The corrected errors are fitted by ``log e = c + k log spp`` (``k = -1/2`` for
independent samples; stratified ones fall faster), and the time per call by ``seconds = t0 + b
spp``; both give the spp and the seconds per sample at which the error is :data:`TARGET_ERROR`.

JIT compilation: every ``spp`` and configuration compiles its own kernels (``spp`` is compiled
in), in the first call of the point (its warm-up). Each configuration reports that first call
(``first_call_seconds_incl_jit``) and the renderer's ``seconds["jit_compile"]`` of the first
and of the later calls (0 when the kernels are reused); the timed calls exclude compilation.
"""

from __future__ import annotations

import dataclasses
import math
import subprocess
from collections.abc import Collection, Mapping

import numpy as np

from network.bench.timing import RULE, machine, time_call
from network.metrics import normal_angle_deg
from pbrdf.sensor import decode

__all__ = ["run", "fit_to_target", "TARGET_ERROR", "CONFIGS"]

#: Relative unpol/LP RMSE at which the configurations are compared.
TARGET_ERROR = 0.02
#: Configuration name -> (settings changed from the renderer's defaults, what it renders in words).
CONFIGS = {
    "default": (
        {},
        "polarized display emitter (no sheet), integrator auto (direct where direct light is all, else path), "
        "multijitter, crop window, max_depth auto",
    ),
    "sheet": (
        {"display": "sheet"},
        "display behind a polarizer sheet, volpath (shadow rays through the sheet), multijitter, crop window, "
        "max_depth auto",
    ),
    "naive_path": (
        {"display": "sheet", "integrator": "path", "sampler": "independent", "crop": False},
        "sheet, path (no shadow rays through the sheet), independent sampler, full frame, max_depth auto",
    ),
    "naive_volpath": (
        {"display": "sheet", "integrator": "volpath", "sampler": "independent", "crop": False},
        "sheet, volpath, independent sampler, full frame, max_depth auto",
    ),
}


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


def fit_to_target(points: list[dict], ref_var: float, target: float = TARGET_ERROR) -> dict:
    """Samples per pixel and seconds per call at which the corrected error reaches ``target``.

    Args:
        points: ``{"spp", "seconds", "rel_rmse_unpol_lp"}`` per benchmark point.
        ref_var: the reference's own error variance ``e_ref^2``, subtracted from each squared error.
        target: the error to reach.

    Returns:
        ``rel_rmse_corrected`` per point, ``error_exponent`` (``k`` of ``e ~ spp^k``; -0.5 with
        one usable point), ``spp_for_2pct``, ``seconds_per_sample_at_2pct``, and the time model
        ``seconds_fixed`` + ``seconds_per_spp`` x spp. None where the points do not allow it.

    Example:
        Error 0.4 / sqrt(spp) on top of a reference error of 0.01, 0.1 s + 0.01 s per spp:

        >>> err = lambda s: (0.16 / s + 1e-4) ** 0.5
        >>> pts = [{"spp": s, "seconds": 0.1 + 0.01 * s, "rel_rmse_unpol_lp": err(s)} for s in (4, 16)]
        >>> f = fit_to_target(pts, ref_var=1e-4)
        >>> round(f["error_exponent"], 3), round(f["spp_for_2pct"], 1), round(f["seconds_per_sample_at_2pct"], 3)
        (-0.5, 400.0, 4.1)
    """
    spp = np.array([p["spp"] for p in points], dtype=float)
    sec = np.array([p["seconds"] for p in points], dtype=float)
    err2 = np.array([p["rel_rmse_unpol_lp"] for p in points], dtype=float) ** 2 - ref_var
    corrected = [math.sqrt(e) if e > 0 else None for e in err2]
    ok = err2 > 0
    out: dict = {"rel_rmse_corrected": corrected, "error_exponent": None, "spp_for_2pct": None}
    if ok.sum() >= 2:
        k, c = np.polyfit(np.log(spp[ok]), 0.5 * np.log(err2[ok]), 1)
    elif ok.sum() == 1:
        k, c = -0.5, float(0.5 * np.log(err2[ok][0]) + 0.5 * np.log(spp[ok][0]))
    if ok.any() and k < 0:
        out["error_exponent"] = float(k)
        out["spp_for_2pct"] = float(np.exp((np.log(target) - c) / k))
    if len(spp) >= 2 and np.ptp(spp) > 0:
        b, t0 = np.polyfit(spp, sec, 1)
        # Timing noise on a loaded machine can give a negative intercept or slope: fall back to
        # seconds proportional to spp, which stays positive.
        b, t0 = (b, t0) if t0 >= 0 and b > 0 else (float(np.sum(sec * spp) / np.sum(spp * spp)), 0.0)
    else:
        b, t0 = float(sec[0] / spp[0]), 0.0
    out["seconds_fixed"], out["seconds_per_spp"] = float(t0), float(b)
    out["seconds_per_sample_at_2pct"] = None if out["spp_for_2pct"] is None else float(t0 + b * out["spp_for_2pct"])
    return out


def _scene(
    render, name: str, spec, *, resolution, ref_spp, spp, repeat, warmup, seed, naive: bool, variant: str
) -> dict:
    spec = dataclasses.replace(spec, seed=seed)
    base = render.RenderSettings(resolution=resolution, spp=1, variant=variant)
    chunk = max(spp) if ref_spp % max(spp) == 0 else 64
    ref_timing, ref = time_call(
        lambda: _render_avg(render, spec, base, ref_spp, chunk),
        f"reference of {name!r}: default configuration, {ref_spp} spp in chunks of {chunk} with distinct seeds, "
        "averaged (one call, not a benchmark point)",
        repeat=1,
        warmup=0,
    )
    mask = ref.mask
    ref_maps = _maps(ref.stokes)[mask]
    ref_norm = np.sqrt(np.mean(ref_maps[..., :6] ** 2))
    off = ref.window.offset
    out: dict = {
        "reference": ref_timing.to_dict(),
        "reference_seconds": ref_timing.median,
        "reference_chunk_spp": chunk,
        "max_depth": ref.max_depth,
        "object_pixels": int(mask.sum()),
        "configs": {},
    }
    for cfg, (changes, label) in CONFIGS.items():
        if cfg.startswith("naive") and not naive:
            continue
        settings = dataclasses.replace(base, **changes)
        entry: dict = {"what": label, "settings": {k: getattr(settings, k) for k in ("integrator", "sampler", "crop")}}
        points, compile_first, compile_later = [], [], []
        for n_spp in spp:
            point_spec = dataclasses.replace(spec, seed=seed + n_spp)
            point_settings = dataclasses.replace(settings, spp=n_spp)
            calls: list = []

            def call(s=point_spec, st=point_settings, calls=calls):
                r = render.render_stokes(s, st)
                calls.append(r.seconds.get("jit_compile"))
                return r

            timing, res = time_call(
                call,
                f"{name}: render_stokes (3 colour passes, one dataset sample), {label}, {resolution} px crop, "
                f"{n_spp} spp",
                repeat=repeat,
                warmup=warmup,
            )
            compile_first.append(calls[0])
            compile_later += calls[1:]
            if not points and timing.warmup:
                entry["first_call_seconds_incl_jit"] = timing.warmup[0]
            entry["max_depth"] = res.max_depth
            stokes = res.stokes
            if not settings.crop:  # the crop window's pixels inside the full film
                stokes = stokes[off[1] : off[1] + mask.shape[0], off[0] : off[0] + mask.shape[1]]
            maps = _maps(stokes)[mask]
            rel = float(np.sqrt(np.mean((maps[..., :6] - ref_maps[..., :6]) ** 2)) / ref_norm)
            cp_rmse = float(np.sqrt(np.mean((maps[..., 6:] - ref_maps[..., 6:]) ** 2)))
            normal_deg = float(normal_angle_deg(res.normal[mask], ref.normal[mask]).mean()) if settings.crop else None
            samples = res.stokes.shape[0] * res.stokes.shape[1]
            points.append({
                "spp": n_spp, **timing.to_dict(), "seconds": timing.median, "rel_rmse_unpol_lp": rel,
                "rmse_cp": cp_rmse, "normal_error_deg": normal_deg, "pixels": samples,
                "msamples_per_second": 3 * samples * n_spp / timing.median / 1e6,
            })  # fmt: skip
        entry["points"] = points
        entry["jit_compile_seconds_first_call"] = compile_first
        entry["jit_compile_seconds_later_calls_max"] = max(compile_later, default=None)
        out["configs"][cfg] = entry
    # The reference's own noise, from the default configuration at the chunk size (if timed).
    default = out["configs"]["default"]["points"]
    at_chunk = [p for p in default if p["spp"] == chunk]
    ref_var = 0.0
    if at_chunk:
        ref_var = at_chunk[0]["rel_rmse_unpol_lp"] ** 2 * chunk / (ref_spp + chunk)
    out["reference_rel_rmse_estimate"] = math.sqrt(ref_var)
    for entry in out["configs"].values():
        entry.update(fit_to_target(entry["points"], ref_var))
    t_default = out["configs"]["default"]["seconds_per_sample_at_2pct"]
    for cfg in out["configs"]:
        t = out["configs"][cfg]["seconds_per_sample_at_2pct"]
        if cfg != "default":
            out[f"speedup_default_over_{cfg}_at_2pct"] = t / t_default if t and t_default else None
    return out


def run(
    render,
    scenes: Mapping[str, tuple],
    *,
    resolution: int = 384,
    ref_spp: int = 1024,
    spp: tuple[int, ...] = (4, 8, 16, 32, 64),
    repeat: int = 1,
    warmup: int = 1,
    seed: int = 0,
    naive: Collection[str] | None = None,
    variant: str = "llvm",
) -> dict:
    """Run the benchmark.

    Args:
        render: the renderer module (``render_stokes``, ``RenderSettings``, ``choose_variant``;
            ``blender_addon.core.render``).
        scenes: name -> ``(spec, description)`` of each scene to render.
        resolution: crop size in pixels.
        ref_spp: samples per pixel of each reference.
        spp: sample counts to time, ascending.
        repeat: timed renders per point.
        warmup: untimed renders per point before them (the first compiles that point's kernels).
        seed: point ``spp`` renders with seed ``seed + spp``.
        naive: scenes that also get the naive configurations (default: all).
        variant: Mitsuba variant or alias of ``choose_variant`` (``llvm``, ``cuda``, ``auto``).

    Returns:
        The JSON-ready result: ``scenes`` -> name -> ``description``, ``reference``,
        ``max_depth``, ``reference_rel_rmse_estimate``, ``configs`` (per configuration ``what``,
        ``points``, ``first_call_seconds_incl_jit``, ``jit_compile_seconds_first_call`` per
        point, ``jit_compile_seconds_later_calls_max``, ``spp_for_2pct``,
        ``seconds_per_sample_at_2pct``, the fits) and ``speedup_default_over_<naive>_at_2pct``;
        ``timing_rule``, ``machine``.
    """
    variant = render.choose_variant(variant)
    result: dict = {
        "benchmark": "render",
        "resolution": resolution,
        "reference_spp": ref_spp,
        "spp": list(spp),
        "variant": variant,
        "target_rel_rmse_unpol_lp": TARGET_ERROR,
        "timing_rule": RULE,
        "scenes": {},
    }
    for name, (spec, description) in scenes.items():
        entry = _scene(
            render, name, spec, resolution=resolution, ref_spp=ref_spp, spp=tuple(spp), repeat=repeat,
            warmup=warmup, seed=seed, naive=naive is None or name in naive, variant=variant,
        )  # fmt: skip
        result["scenes"][name] = {"description": description, **entry}
    result["machine"] = machine(**({"gpu": _gpu_name()} if variant.startswith("cuda") else {}))
    return result


def _gpu_name() -> str:
    """The first GPU's name from ``nvidia-smi`` (``unknown`` where it does not answer)."""
    try:
        cmd = ["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"]
        out = subprocess.run(cmd, capture_output=True, text=True, check=False)
        return out.stdout.splitlines()[0].strip() if out.returncode == 0 and out.stdout.strip() else "unknown"
    except OSError:
        return "unknown"
