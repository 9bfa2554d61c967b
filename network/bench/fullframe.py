"""A full-frame capture through the whole inference path, stage by stage, and its strides against stride 1.

:func:`profile` times each stage of what ``headless/infer.py`` does to one capture folder, in one process:
reading the raw brackets, decoding them into the nine maps, the object mask, the crop and encoder, the per-pixel
decoder, the relief depth integration with the maps written meanwhile (one stage, overlapped as there), the glTF
binary (and, where ``blend`` is set and the bpy wheel is installed, the ``.blend`` in its own process as
``--blend`` does). :func:`stride_rows` decodes the
same capture at stride 1 and at each of the given strides (edge-aware, the default ``refine_deg``) and reports the
time of :func:`network.infer.predict` and the error of each against stride 1 (normal angle p99, BRDF RMSE), the
tolerance the defaults must keep (:data:`TOLERANCE`). :func:`depth_rows` integrates the capture's predicted normals
with both preconditioners of :func:`pbrdf.geometry.normal_integration.integrate_normals` (the default two-grid and
algebraic multigrid, ``cell=1``), side by side, and reports their seconds and their difference
(:func:`depth_error`: relative to the object's depth range, and as the angle between the integrated surfaces).
:func:`refine_rows` (the ``refine`` variant) times the maps with and without the test-time refinement
(``infer.py --no-refine`` against its default where a distance is known), side by side, and the refinement's
own seconds (``RefineResult.seconds``).

Example:
    >>> rows = {"decode": 1.0, "predict": 3.0}
    >>> print(stage_table(rows, total=4.0).splitlines()[2])
    | decode | 1.00 | 25 % |
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

import numpy as np

__all__ = [
    "TOLERANCE",
    "depth_error",
    "depth_rows",
    "profile",
    "refine_rows",
    "stage_table",
    "stride_error",
    "stride_rows",
]

#: What a faster default must keep against the stride-1 full-resolution answer (issue 30): normal angle p99 in
#: degrees, and RMSE of albedo, roughness and metallic.
TOLERANCE = {"normal_deg_p99": 1.0, "brdf_rmse": 0.01}


class _Clock:
    """Named stage timings, in the order they were first timed (a repeated stage adds up)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    @contextmanager
    def stage(self, name: str):
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start

    def wrap(self, name: str, fn: Callable) -> Callable:
        def timed(*args, **kwargs):
            with self.stage(name):
                return fn(*args, **kwargs)

        return timed


def stage_table(seconds: dict[str, float], total: float) -> str:
    """A Markdown table of stage seconds and their share of ``total``."""
    lines = ["| stage | seconds | share |", "|---|---:|---:|"]
    lines += [f"| {name} | {s:.2f} | {100 * s / total:.0f} % |" for name, s in seconds.items()]
    return "\n".join(lines)


def profile(capture: Path, checkpoint: Path, *, stride: int | None = None, blend: bool = False) -> dict:
    """Seconds per stage of one capture's reconstruction (what ``headless/infer.py --gltf [--blend]`` does).

    Args:
        capture: a capture folder (raw brackets + ``capture.json``).
        checkpoint: the model.
        stride: :func:`network.infer.predict`'s ``stride``; None: ``headless/infer.py``'s default
            (:func:`network.model.dense.auto_stride`, with :func:`network.infer.auto_refine_deg`).
        blend: also time the ``.blend`` (``headless/relight.py --save-blend`` in its own process; skipped with a
            note when bpy is not installed).

    Returns:
        ``{"stages": {name: seconds}, "total_seconds", "table" (Markdown), "frame" (raw and decoded sizes, masked
        share), "notes"}``.
    """
    import torch  # noqa: PLC0415

    from network.checkpoint import load_checkpoint  # noqa: PLC0415
    from network.infer import auto_refine_deg, predict, relief_depth  # noqa: PLC0415
    from network.model.dense import REFINE_DEG, auto_stride  # noqa: PLC0415
    from pbrdf.data import capture as pcapture  # noqa: PLC0415
    from pbrdf.data import capture_decode  # noqa: PLC0415
    from pbrdf.data.gltf_asset import build_asset, write_asset  # noqa: PLC0415
    from pbrdf.data.predictions import CameraRecord, write_predictions  # noqa: PLC0415

    clock, notes = _Clock(), []
    model, ckpt = load_checkpoint(checkpoint)
    start = time.perf_counter()
    with clock.stage("read the raw brackets"):
        cap = pcapture.load_capture(capture)
    with clock.stage("decode the nine maps"):
        dec = capture_decode.decode_capture(cap)
    with clock.stage("object mask (foreground)"):
        capture_decode.check_usable(dec, cap, need_object=True)
        mask = dec.input_mask
    k = cap.meta.grid_intrinsics(cap.raws.shape[1:], dec.maps.shape[:2])
    refine = auto_refine_deg(int(mask.sum())) if stride is None else REFINE_DEG
    stride = auto_stride(int(mask.sum())) if stride is None else stride
    model.encode = clock.wrap("encoder (crop resized to the input size)", model.encode)
    model.decode_dense = clock.wrap("per-pixel decoder", model.decode_dense)
    with clock.stage("crop, normalise, paste back"), torch.inference_mode():
        pred = predict(model, dec.maps, mask, inputs=ckpt["inputs"], input_scale=ckpt["input_scale"],
                       radiance=cap.meta.radiance, stride=stride, refine_deg=refine)  # fmt: skip
    inner = clock.seconds["encoder (crop resized to the input size)"] + clock.seconds["per-pixel decoder"]
    clock.seconds["crop, normalise, paste back"] -= inner
    camera = CameraRecord.of_maps(k, mask.shape, cap.meta.distance_m)
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(1) as pool:
        # As headless/infer.py (headless._overlap): the relief integrates on a thread while the maps are written.
        with clock.stage("relief depth integration, the maps written (EXR + PNG) meanwhile"):
            relief = pool.submit(lambda: {"depth": relief_depth(pred, k, cap.meta.distance_m)})
            write_predictions(tmp, "frame", pred, camera, pending=relief)
        pred["depth"] = relief.result()["depth"]
        with clock.stage("glTF binary"):
            write_asset(Path(tmp) / "frame.glb", build_asset(pred, k, distance=camera.distance_m or 0.75), name="f")
        if blend:
            _time_blend(clock, Path(tmp), notes)
    total = time.perf_counter() - start
    return {
        "stages": clock.seconds,
        "total_seconds": total,
        "table": stage_table(clock.seconds, total),
        "frame": {"raw": list(cap.raws.shape), "decoded": list(mask.shape), "masked_share": float(mask.mean())},
        "stride": stride,
        "threads": torch.get_num_threads(),
        "notes": notes,
    }


def _time_blend(clock: _Clock, folder: Path, notes: list[str]) -> None:
    """The ``.blend`` of ``--blend`` (headless/relight.py in its own process), or a note without bpy."""
    import importlib.util  # noqa: PLC0415

    if importlib.util.find_spec("bpy") is None:
        notes.append(".blend not timed: the bpy wheel is not installed")
        return
    script = Path(__file__).resolve().parents[2] / "headless" / "relight.py"
    cmd = [sys.executable, str(script), "--input", str(folder), "--name", "frame", "--out", str(folder),
           "--frames", "0", "--save-blend", "--quiet"]  # fmt: skip
    with clock.stage(".blend (headless/relight.py --save-blend, own process)"):
        proc = subprocess.run(cmd, check=False, capture_output=True, text=True)
    if proc.returncode:
        notes.append(f".blend failed: {proc.stderr.strip().splitlines()[-1:]}")


def stride_error(ref: dict[str, np.ndarray], pred: dict[str, np.ndarray], mask: np.ndarray) -> dict[str, float]:
    """Error of ``pred`` against ``ref`` inside ``mask``: normal angle (degrees) and BRDF RMSE per map.

    Args:
        ref: ``{"normal", "albedo", "roughness", "metallic"}`` ``(H, W, C)`` maps (the stride-1 answer).
        pred: the same maps from another setting.
        mask: ``(H, W)`` bool.

    Returns:
        ``normal_deg_p99``, ``normal_deg_max``, ``<map>_rmse`` (over every channel of the map) and ``within``
        (:data:`TOLERANCE` holds).

    Example:
        >>> m = np.ones((2, 2), bool)
        >>> a = {"normal": np.tile([0.0, 0, 1], (2, 2, 1)), "albedo": np.zeros((2, 2, 3)),
        ...      "roughness": np.zeros((2, 2, 1)), "metallic": np.zeros((2, 2, 1))}
        >>> b = dict(a, albedo=np.full((2, 2, 3), 0.02))
        >>> e = stride_error(a, b, m)
        >>> round(e["albedo_rmse"], 3), e["within"]
        (0.02, False)
    """
    a, b = ref["normal"][mask].astype(np.float64), pred["normal"][mask].astype(np.float64)
    # atan2 of |a x b| and a . b: exact near 0 deg, where arccos of a float32 dot product reads 0.03 deg
    deg = np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))
    out = {"normal_deg_p99": float(np.quantile(deg, 0.99)), "normal_deg_max": float(deg.max())}
    for key in ("albedo", "roughness", "metallic"):
        out[f"{key}_rmse"] = float(np.sqrt(np.mean((ref[key][mask] - pred[key][mask]) ** 2)))
    worst = max(out[f"{key}_rmse"] for key in ("albedo", "roughness", "metallic"))
    out["within"] = bool(out["normal_deg_p99"] <= TOLERANCE["normal_deg_p99"] and worst <= TOLERANCE["brdf_rmse"])
    return out


def stride_rows(
    capture: Path, checkpoint: Path, strides: tuple[int, ...] = (2, 4), *, repeat: int = 1, warmup: int = 1
) -> dict:
    """:func:`network.infer.predict` on a capture at stride 1 and at each stride, side by side: time and error.

    Args:
        capture: a capture folder or sample.
        checkpoint: the model.
        strides: strides to compare with stride 1 (edge-aware, the default ``refine_deg``).
        repeat: timed calls per row (the median is reported).
        warmup: untimed calls before them.

    Returns:
        ``{"masked_pixels", "rows": {"stride_s": {"what", "seconds_median", "seconds_all",
        "error_vs_stride_1"}}}``.
    """
    from network.bench.timing import time_call  # noqa: PLC0415
    from network.checkpoint import load_checkpoint  # noqa: PLC0415
    from network.infer import load_input, predict  # noqa: PLC0415

    model, ckpt = load_checkpoint(checkpoint)
    inp = load_input(capture, require_object=True)
    rows, ref = {}, None
    for stride in (1, *[s for s in strides if s != 1]):
        what = (f"network.infer.predict of {Path(capture).name} ({inp.mask.shape[1]} x {inp.mask.shape[0]} decoded, "
                f"{int(inp.mask.sum())} masked pixels) at full resolution, stride {stride}: encoder + per-pixel "
                "decoder (no decode of the raws, no depth)")  # fmt: skip
        timing, pred = time_call(
            lambda s=stride: predict(model, inp.maps, inp.mask, inputs=ckpt["inputs"], input_scale=ckpt["input_scale"],
                                     radiance=inp.radiance, stride=s),
            what, repeat=repeat, warmup=warmup,
        )  # fmt: skip
        row = timing.to_dict()
        ref = pred if stride == 1 else ref
        row["error_vs_stride_1"] = stride_error(ref, pred, inp.mask)
        rows[f"stride_{stride}"] = row
    return {"masked_pixels": int(inp.mask.sum()), "tolerance": TOLERANCE, "rows": rows}


def surface_normals(depth: np.ndarray, intrinsics: np.ndarray) -> np.ndarray:
    """``(H - 1, W - 1, 3)`` unit normals of the surface through the depth map's points (camera frame, OpenGL).

    Each 2x2 block's normal is the cross product of its points' steps along a row and down a column.
    """
    from pbrdf.sensor.projection import pixel_rays  # noqa: PLC0415

    pts = pixel_rays(intrinsics, *depth.shape) * depth[..., None].astype(np.float64)
    n = np.cross(pts[:-1, 1:] - pts[:-1, :-1], pts[1:, :-1] - pts[:-1, :-1])
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)


def depth_error(ref: np.ndarray, got: np.ndarray, mask: np.ndarray, intrinsics: np.ndarray) -> dict[str, float]:
    """How far depth ``got`` is from ``ref`` on ``mask``: relative to the object's depth range, and in surface angle.

    Args:
        ref: ``(H, W)`` the reference depth (m).
        got: ``(H, W)`` the depth to check.
        mask: ``(H, W)`` bool.
        intrinsics: ``K (3, 3)`` of the maps' grid.

    Returns:
        ``range_m`` (p99 - p1 of ``ref`` on the mask), ``depth_rel_p50``, ``depth_rel_p99``, ``depth_rel_max``
        (``|got - ref|`` over that range) and ``surface_deg_p50``, ``surface_deg_p99`` (angle between the two
        surfaces' normals, :func:`surface_normals`, on 2x2 blocks inside the mask).

    Example:
        >>> k = np.array([[100.0, 0, 8], [0, 100.0, 8], [0, 0, 1]])
        >>> m = np.ones((16, 16), bool)
        >>> ref = np.linspace(0.7, 0.8, 16)[None].repeat(16, 0)
        >>> e = depth_error(ref, ref + 0.001, m, k)
        >>> round(e["depth_rel_max"], 3)
        0.011
    """
    rng = float(np.quantile(ref[mask], 0.99) - np.quantile(ref[mask], 0.01))
    rel = np.abs(got[mask].astype(np.float64) - ref[mask]) / max(rng, 1e-12)
    block = mask[:-1, :-1] & mask[1:, :-1] & mask[:-1, 1:] & mask[1:, 1:]
    a, b = surface_normals(ref, intrinsics)[block], surface_normals(got, intrinsics)[block]
    deg = np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))
    return {
        "range_m": rng,
        "depth_rel_p50": float(np.median(rel)),
        "depth_rel_p99": float(np.quantile(rel, 0.99)),
        "depth_rel_max": float(rel.max()),
        "surface_deg_p50": float(np.median(deg)) if deg.size else 0.0,
        "surface_deg_p99": float(np.quantile(deg, 0.99)) if deg.size else 0.0,
    }


def depth_rows(capture: Path, checkpoint: Path, *, stride: int | None = None, repeat: int = 3) -> dict:
    """The relief depth of a capture's predicted normals by both preconditioners, side by side: seconds and error.

    Args:
        capture: a capture folder or sample.
        checkpoint: the model.
        stride: :func:`network.infer.predict`'s ``stride`` (None: :func:`network.model.dense.auto_stride`).
        repeat: timed integrations per route, interleaved (the medians are reported).

    Returns:
        ``{"masked_pixels", "rows": {"two_grid" | "multigrid": {"what", "wall_median", "cpu_median", "wall_all",
        "cpu_all"}}, "two_grid_vs_multigrid": depth_error(...)}``.
    """
    from network.checkpoint import load_checkpoint  # noqa: PLC0415
    from network.infer import load_input, predict  # noqa: PLC0415
    from network.model.dense import auto_stride  # noqa: PLC0415
    from pbrdf.data.capture_meta import DEFAULT_DISTANCE_M  # noqa: PLC0415
    from pbrdf.geometry.normal_integration import auto_cell, integrate_normals  # noqa: PLC0415

    model, ckpt = load_checkpoint(checkpoint)
    inp = load_input(capture, require_object=True)
    pixels = int(inp.mask.sum())
    pred = predict(model, inp.maps, inp.mask, inputs=ckpt["inputs"], input_scale=ckpt["input_scale"],
                   radiance=inp.radiance, stride=auto_stride(pixels) if stride is None else stride)  # fmt: skip
    distance = inp.distance_m or DEFAULT_DISTANCE_M
    routes = {"two_grid": None, "multigrid": 1}
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in routes}
    depth = {}
    for _ in range(max(1, repeat)):
        for name, cell in routes.items():
            wall, cpu = time.perf_counter(), time.process_time()
            depth[name] = integrate_normals(pred["normal"], inp.mask, inp.intrinsics, distance, cell=cell)
            times[name].append((time.perf_counter() - wall, time.process_time() - cpu))
    rows = {}
    for name, cell in routes.items():
        wall, cpu = (sorted(t[j] for t in times[name]) for j in (0, 1))
        how = f"two-grid preconditioner, cells of {auto_cell(pixels)} px" if cell is None else "algebraic multigrid"
        what = f"integrate_normals of {pixels} predicted normals, {how}"
        rows[name] = {"what": what, "wall_median": wall[len(wall) // 2], "cpu_median": cpu[len(cpu) // 2],
                      "wall_all": [t[0] for t in times[name]], "cpu_all": [t[1] for t in times[name]]}  # fmt: skip
    error = depth_error(depth["multigrid"], depth["two_grid"], inp.mask, inp.intrinsics)
    return {"masked_pixels": pixels, "rows": rows, "two_grid_vs_multigrid": error}


def refine_rows(capture: Path, checkpoint: Path, *, repeat: int = 3, warmup: int = 1) -> dict:
    """The maps without and with the test-time refinement, side by side (calls alternating): wall and CPU seconds.

    ``no_refine`` is :func:`network.infer.predict` as ``infer.py --no-refine`` runs it (the auto stride);
    ``refine`` is the same call, then :func:`network.refine.refine_input` at the capture's ``distance_m`` (else
    0.75 m, as ``--refine``), what ``infer.py`` does by default where a distance is known. No decode of the raws,
    no depth, no files: the difference is the refinement's cost per capture.

    Args:
        capture: a capture folder (a calibrated one: else nothing is refined).
        checkpoint: the model.
        repeat: timed rounds (medians reported), >= 1.
        warmup: untimed rounds before them.

    Returns:
        ``{"masked_pixels", "distance_m", "rows": {"no_refine" | "refine": {time_call's entry, "cpu_median",
        "cpu_all"}}, "refine_seconds_median", "refine_seconds_all" (the refinement's wall seconds),
        "refine_cpu_median", "refine_cpu_all" (its CPU seconds, all threads), "refined", "message", "changed_maps"}``;
        ``changed_maps``: the maps that differ between the two (at most ``["albedo"]``).
    """
    from network.bench.timing import time_interleaved  # noqa: PLC0415
    from network.checkpoint import load_checkpoint  # noqa: PLC0415
    from network.infer import auto_refine_deg, load_input, predict  # noqa: PLC0415
    from network.model.dense import auto_stride  # noqa: PLC0415
    from network.refine import refine_input  # noqa: PLC0415

    model, ckpt = load_checkpoint(checkpoint)
    inp = load_input(capture, require_object=True)
    pixels = int(inp.mask.sum())
    kw = {"inputs": ckpt["inputs"], "input_scale": ckpt["input_scale"], "radiance": inp.radiance,
          "stride": auto_stride(pixels), "refine_deg": auto_refine_deg(pixels)}  # fmt: skip
    cpu: dict[str, list[float]] = {"no_refine": [], "refine": []}
    fits = []

    def network():
        start = time.process_time()
        pred = predict(model, inp.maps, inp.mask, **kw)
        cpu["no_refine"].append(time.process_time() - start)
        return pred

    def refined():
        start = time.process_time()
        pred = predict(model, inp.maps, inp.mask, **kw)
        between = time.process_time()
        res = refine_input(pred, inp, warn=False)
        cpu["refine"].append(time.process_time() - start)
        fits.append((res, time.process_time() - between))
        return res.pred

    size = f"{Path(capture).name} ({inp.mask.shape[1]} x {inp.mask.shape[0]} decoded, {pixels} masked pixels)"
    out = time_interleaved({
        "no_refine": (network, f"network.infer.predict of {size}, stride {kw['stride']}: infer.py --no-refine's maps"),
        "refine": (refined, f"the same predict, then network.refine.refine_input at distance_m {inp.distance_m}: "
                            "infer.py's default refinement (a distance known)"),
    }, repeat=repeat, warmup=warmup)  # fmt: skip
    rows = {}
    for name, (timing, _) in out.items():
        timed = cpu[name][warmup:]
        rows[name] = {**timing.to_dict(), "cpu_median": float(np.median(timed)), "cpu_all": timed}
    base, ref = out["no_refine"][1], out["refine"][1]
    seconds = [f.seconds for f, _ in fits[warmup:]]
    fit_cpu = [c for _, c in fits[warmup:]]
    return {
        "masked_pixels": pixels,
        "distance_m": inp.distance_m,
        "rows": rows,
        "refine_seconds_median": float(np.median(seconds)),
        "refine_seconds_all": seconds,
        "refine_cpu_median": float(np.median(fit_cpu)),
        "refine_cpu_all": fit_cpu,
        "refined": fits[-1][0].refined,
        "message": fits[-1][0].message,
        "changed_maps": [k for k in base if not np.array_equal(base[k], ref[k])],
    }
