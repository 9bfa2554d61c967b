"""Benchmarks with JSON output: run time against error, measured side by side in one run.

Usage:
    python headless/bench.py decode [--height 2048 --width 2448] [--repeat 5] [--out FILE]
    python headless/bench.py render [--resolution 384] [--ref-spp 1024] [--spp 4 8 16 32 64] [--out FILE]
    python headless/bench.py pbrdf [--count 40] [--out FILE]
    python headless/bench.py network [--configs toy small paper] [--out FILE]

``decode``: a 2448x2048 IMX250MYR raw bracket (four exposures) decoded into the nine maps by
:func:`pbrdf.decode.decode` on the half and full grids, next to polanalyser 3.0's single-bracket
demosaic + Stokes of the same mosaic (the reference implementation; skipped with a note if it is
not installed). Reports median wall time, peak traced memory, the speed ratio and the error of
each route on a noise-free scene whose exact Stokes images are known.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pbrdf import camera, decode  # noqa: E402
from pbrdf import stokes as pstokes  # noqa: E402


def _timed(fn, repeat: int) -> tuple[float, list[float]]:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def _peak_mib(fn) -> float:
    tracemalloc.start()
    tracemalloc.reset_peak()
    fn()
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak / 2**20


def _scene(h: int, w: int) -> np.ndarray:
    """Smooth, fully known Stokes images (H, W, 3, 4): an affine-in-space mix of states."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    u, v = yy / h, xx / w
    s = np.empty((h, w, 3, 4))
    for c in range(3):
        s0 = 0.05 + 0.5 * u + 0.2 * v + 0.1 * c
        s[..., c, :] = pstokes.stokes(s0, 0.2 + 0.5 * v, 0.3 + c + 0.5 * u, 0.1 * (c - 1) * u)
    return s


def bench_decode(args: argparse.Namespace) -> dict:
    h, w = args.height, args.width
    model = camera.CameraModel()
    rng = np.random.default_rng(args.seed)
    truth = _scene(h, w)
    raws = camera.simulate_capture(truth, model, rng=rng, noise=True)
    result: dict = {"benchmark": "decode", "height": h, "width": w, "brackets": len(model.exposures)}

    # Float-exactness on a noise-free float mosaic (no quantisation): pure interpolation error.
    exact_model = model.replace(
        exposures=(1.0,), sensor=camera.SensorParams(black_level=0.0, bits=16, electrons_per_unit=1 / 0.38)
    )
    mosaic = camera.mosaic(truth, exact_model).astype(np.float32)
    ref3 = truth[..., [0, 1, 3]]
    margin = 8

    for grid in ("half", "full"):
        med, times = _timed(lambda g=grid: decode.decode(raws, model, grid=g), args.repeat)
        peak = _peak_mib(lambda g=grid: decode.decode(raws, model, grid=g))
        dec = decode.decode(mosaic[None], exact_model, grid=grid)
        if grid == "half":
            ref = ref3.reshape(h // 2, 2, w // 2, 2, 3, 3).mean(axis=(1, 3))
            m = margin // 2
        else:
            ref = ref3
            m = margin
        err = np.abs(dec.stokes - ref)[m:-m, m:-m].max()
        result[f"ours_{grid}"] = {
            "seconds_median": med,
            "seconds_all": times,
            "peak_mib": peak,
            "output_shape": list(dec.maps.shape),
            "stokes_max_abs_error_noise_free": float(err),
        }

    try:
        import polanalyser as pa  # noqa: PLC0415
    except Exception as exc:  # noqa: BLE001 - report any import failure in the JSON
        result["polanalyser"] = {"skipped": f"polanalyser unavailable: {exc}"}
    else:
        angles = np.deg2rad([0, 45, 90, 135])
        raw0 = raws[-1]

        def pa_route(raw=raw0):
            imgs = pa.demosaicing(raw, pa.COLOR_PolarRGB)
            return pa.calcStokes(imgs, angles)

        med, times = _timed(pa_route, args.repeat)
        peak = _peak_mib(pa_route)
        # Its error on the same noise-free scene, scaled to 16 bit (its input must be integer).
        scale = 65535.0 / mosaic.max()
        st = pa.calcStokes(pa.demosaicing(np.rint(mosaic * scale).astype(np.uint16), pa.COLOR_PolarRGB), angles)
        st = st[..., ::-1, :] / scale  # BGR -> RGB
        pa3 = np.stack([st[..., 0], st[..., 1], st[..., 2]], axis=-1)  # its s2 channel is our s3
        err = np.abs(pa3 - ref3)[margin:-margin, margin:-margin].max()
        result["polanalyser"] = {
            "version": getattr(pa, "__version__", "3.0.0"),
            "route": "demosaicing(COLOR_PolarRGB) + calcStokes, one bracket",
            "seconds_median": med,
            "seconds_all": times,
            "peak_mib": peak,
            "stokes_max_abs_error_noise_free_16bit": float(err),
        }
        result["speed_ratio_polanalyser_1_bracket_over_ours_4_brackets_half"] = (
            med / result["ours_half"]["seconds_median"]
        )
        result["speed_ratio_polanalyser_1_bracket_over_ours_4_brackets_full"] = (
            med / result["ours_full"]["seconds_median"]
        )
    result["machine"] = {"cpus": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__}
    return result


def _bench_scene():
    from blender_addon.core.rig import Rig  # noqa: PLC0415
    from blender_addon.core.spec import MaterialSpec, ObjectSpec, SceneSpec  # noqa: PLC0415

    m = np.eye(4)
    m[:3, :3] *= 0.25
    m[:3, 3] = (0.03, -0.02, -0.7)
    mat = MaterialSpec.plastic("plastic", (0.6, 0.4, 0.2), roughness=0.3)
    obj = ObjectSpec("blob", "builtin:blob?seed=1", tuple(map(tuple, m)), "plastic")
    return SceneSpec(rig=Rig(), objects=(obj,), materials=(mat,), seed=0)


def _render_avg(spec, settings, spp: int, chunk: int):
    """Render ``spp`` samples as passes of at most ``chunk`` (bounded memory), averaged."""
    import dataclasses  # noqa: PLC0415

    from blender_addon.core import render  # noqa: PLC0415

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
    return decode.nine_maps(stokes[..., [0, 1, 3]], eps=1e-3)


def bench_render(args: argparse.Namespace) -> dict:
    import dataclasses  # noqa: PLC0415

    from blender_addon.core import render  # noqa: PLC0415

    spec = _bench_scene()
    base = render.RenderSettings(resolution=args.resolution, spp=1)
    variant = render.choose_variant()
    result: dict = {
        "benchmark": "render",
        "resolution": args.resolution,
        "reference_spp": args.ref_spp,
        "variant": variant,
        "scene": "blob, pplastic albedo (0.6, 0.4, 0.2), roughness 0.3, 0.7 m",
    }
    t0 = time.perf_counter()
    ref = _render_avg(spec, base, args.ref_spp, 64)  # chunks of 64 spp with distinct seeds
    result["reference_seconds"] = time.perf_counter() - t0
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
        t0 = time.perf_counter()
        render.render_stokes(spec, dataclasses.replace(settings, spp=1))
        entry["first_call_seconds_incl_jit"] = time.perf_counter() - t0
        for spp in args.spp:
            t0 = time.perf_counter()
            res = render.render_stokes(dataclasses.replace(spec, seed=spp), dataclasses.replace(settings, spp=spp))
            sec = time.perf_counter() - t0
            stokes = res.stokes
            if not settings.crop:  # the crop window's pixels inside the full film
                stokes = stokes[off[1] : off[1] + mask.shape[0], off[0] : off[0] + mask.shape[1]]
            maps = _maps(stokes)[mask]
            # Relative RMSE of unpol and LP (CP is a ratio with its own scale: reported apart).
            rel = float(np.sqrt(np.mean((maps[..., :6] - ref_maps[..., :6]) ** 2)) / ref_norm)
            cp_rmse = float(np.sqrt(np.mean((maps[..., 6:] - ref_maps[..., 6:]) ** 2)))
            n = res.normal[mask] if settings.crop else None
            normal_deg = (
                float(np.degrees(np.arccos(np.clip(np.sum(n * ref.normal[mask], -1), -1, 1))).mean())
                if n is not None
                else None
            )
            samples = stokes.shape[0] * stokes.shape[1] if settings.crop else res.stokes.shape[0] * res.stokes.shape[1]
            entry["points"].append({
                "spp": spp, "seconds": sec, "rel_rmse_unpol_lp": rel, "rmse_cp": cp_rmse,
                "normal_error_deg": normal_deg, "msamples_per_second": 3 * samples * spp / sec / 1e6,
            })  # fmt: skip
        # err ~ a / sqrt(spp), seconds ~ b * spp: extrapolate the time to 2 % error.
        pts = entry["points"]
        a = np.median([p["rel_rmse_unpol_lp"] * np.sqrt(p["spp"]) for p in pts])
        b = np.median([p["seconds"] / p["spp"] for p in pts])
        entry["spp_for_2pct"] = float((a / 0.02) ** 2)
        entry["seconds_for_2pct"] = float(b * (a / 0.02) ** 2)
        result[name] = entry
    names = list(configs)
    result["speedup_default_over_naive_at_2pct"] = (
        result[names[1]]["seconds_for_2pct"] / result[names[0]]["seconds_for_2pct"]
    )
    result["machine"] = {"cpus": os.cpu_count(), "python": platform.python_version()}
    return result


def bench_pbrdf(args: argparse.Namespace) -> dict:
    from pbrdf import expand, seeds, validity  # noqa: PLC0415
    from pbrdf.expansion_run import ExpansionConfig, run_expansion  # noqa: PLC0415

    result: dict = {"benchmark": "pbrdf", "grid": list(seeds.DEFAULT_GRID)}
    tabs = seeds.seed_tables()
    data = np.stack([np.asarray(t.M, dtype=np.float64).reshape(-1, 5, 4, 4) for t in tabs])
    norm = np.sqrt(np.mean(data**2))
    result["reconstruction"] = []
    for k in (2, 5, 10, 15):
        t0 = time.perf_counter()
        pca = expand.fit_pca(data, k_intensity=k, k_polarization=k)
        rec = expand.reconstruct(pca, expand.project(pca, data))
        result["reconstruction"].append({
            "components": f"{k}+{k}", "seconds": time.perf_counter() - t0,
            "rel_rmse_held_in": float(np.sqrt(np.mean((rec - data) ** 2)) / norm),
        })  # fmt: skip
    mats = data.reshape(-1, 4, 4)
    mats = mats[mats[:, 0, 0] > 1e-8]
    t0 = time.perf_counter()
    ok = validity.is_givens_kostinski(mats) & validity.is_cloude_physical(mats)
    vec = time.perf_counter() - t0
    sub = mats[:2000]
    t0 = time.perf_counter()
    for m in sub:  # plain per-matrix numpy: eig of G M^T G M and eigvalsh of the coherency matrix
        g = np.diag([1.0, -1.0, -1.0, -1.0])
        np.linalg.eig(g @ m.T @ g @ m)
        np.linalg.eigvalsh(validity.coherency_matrix(m))
    loop = (time.perf_counter() - t0) / len(sub) * len(mats)
    result["validity_filter"] = {
        "matrices": int(len(mats)), "valid_fraction": float(ok.mean()),
        "matrices_per_second_vectorised": len(mats) / vec, "matrices_per_second_per_matrix_loop": len(mats) / loop,
        "speedup": loop / vec,
    }  # fmt: skip
    import tempfile  # noqa: PLC0415

    with tempfile.TemporaryDirectory() as tmp:
        cfg = ExpansionConfig(out=Path(tmp), count=args.count, figures=0)
        t0 = time.perf_counter()
        report = run_expansion(cfg, progress=False)
        total = time.perf_counter() - t0
    result["expansion"] = {
        "tables_requested": args.count,
        "written": report.written,
        "acceptance_rate": report.written / max(report.attempts, 1),
        "seconds": total, "stage_seconds": report.seconds,
        "seconds_per_valid_table": report.seconds["generate"] / max(report.written, 1),
        "extrapolated_minutes_for_2000": (
            report.seconds["generate"] / max(report.written, 1) * 2000
            + report.seconds["seeds_and_fits"]
            + report.seconds["pca_and_generator"]
        )
        / 60,
    }  # fmt: skip
    result["machine"] = {"cpus": os.cpu_count(), "python": platform.python_version()}
    return result


def bench_network(args: argparse.Namespace) -> dict:
    import torch  # noqa: PLC0415

    from network.config import get_config  # noqa: PLC0415
    from network.model import PolarInverseModel, count_parameters  # noqa: PLC0415

    result: dict = {"benchmark": "network", "device": "cpu", "threads": torch.get_num_threads(), "configs": {}}
    for name in args.configs:
        cfg = get_config(name)
        torch.manual_seed(0)
        model = PolarInverseModel(cfg)
        size = args.size or cfg.image_size
        maps = torch.rand(1, 9, size, size)
        mask = torch.zeros(1, 1, size, size)
        mask[..., size // 8 : -size // 8, size // 8 : -size // 8] = 1
        entry: dict = {"parameters": count_parameters(model), "image_size": size, "masked_pixels": int(mask.sum())}
        model.train()
        with torch.no_grad():
            model(maps, mask)  # warm-up
            t0 = time.perf_counter()
            model(maps, mask)
            entry["train_forward_seconds"] = time.perf_counter() - t0
        model.train()
        opt = torch.optim.AdamW(model.parameters(), lr=1e-4)
        t0 = time.perf_counter()
        out = model(maps, mask)
        loss = sum(v.float().mean() for k, v in out.items() if k in ("normal", "albedo", "roughness", "metallic"))
        loss.backward()
        opt.step()
        entry["train_step_seconds"] = time.perf_counter() - t0
        if not args.skip_dense or name == "toy":
            model.eval()
            with torch.no_grad():
                t0 = time.perf_counter()
                model(maps, mask)
                sec = time.perf_counter() - t0
            entry["dense_forward_seconds"] = sec
            entry["decoder_pixels_per_second"] = entry["masked_pixels"] / sec
        import resource  # noqa: PLC0415

        entry["process_peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        result["configs"][name] = entry
    result["machine"] = {"cpus": os.cpu_count(), "python": platform.python_version(), "torch": torch.__version__}
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("decode", help="raw HDR bracket -> nine maps, against polanalyser")
    p.add_argument("--height", type=int, default=2048, help="raw height in pixels (default 2048)")
    p.add_argument("--width", type=int, default=2448, help="raw width in pixels (default 2448)")
    p.add_argument("--repeat", type=int, default=5, help="timed repetitions; the median is reported")
    p.add_argument("--seed", type=int, default=0, help="noise seed")
    p.add_argument("--out", type=Path, help="also write the JSON here")
    r = sub.add_parser("render", help="rendered nine maps: error against time, default vs naive configuration")
    r.add_argument("--resolution", type=int, default=384, help="sample size (default 384)")
    r.add_argument("--ref-spp", type=int, default=1024, help="reference samples per pixel (default 1024)")
    r.add_argument("--spp", type=int, nargs="+", default=[4, 8, 16, 32, 64], help="spp values to time")
    r.add_argument("--out", type=Path, help="also write the JSON here")
    q = sub.add_parser("pbrdf", help="PCA error vs components, validity-filter throughput, expansion speed")
    q.add_argument("--count", type=int, default=40, help="tables generated to time the expansion (default 40)")
    q.add_argument("--out", type=Path, help="also write the JSON here")
    nb = sub.add_parser("network", help="forward/step time per model config on this machine")
    nb.add_argument("--configs", nargs="+", default=["toy", "small"], help="configs (default toy small)")
    nb.add_argument("--size", type=int, help="input size (default: the config's)")
    nb.add_argument("--skip-dense", action="store_true", help="skip the dense (all-pixels) forward except for toy")
    nb.add_argument("--out", type=Path, help="also write the JSON here")
    args = parser.parse_args(argv)
    if args.what == "network":
        result = bench_network(args)
    elif args.what == "pbrdf":
        result = bench_pbrdf(args)
    elif args.what == "decode":
        if args.height % 4 or args.width % 4 or min(args.height, args.width) < 32:
            parser.error("--height and --width must be multiples of 4 and at least 32")
        result = bench_decode(args)
    else:
        result = bench_render(args)
    text = json.dumps(result, indent=2)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.out.with_suffix(args.out.suffix + ".tmp")
        tmp.write_text(text + "\n")
        os.replace(tmp, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
