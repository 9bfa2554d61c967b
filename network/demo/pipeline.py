"""The end-to-end demo pipeline behind ``make demo`` (stages, timings, report).

Stages, each timed and shown with a progress bar:

1. ``pbrdf``: expand the built-in analytic seed set into new valid pBRDF tables
   (:func:`pbrdf.expansion.run.run_expansion`).
2. ``render``: random Objaverse-like procedural scenes in front of the polarized display,
   rendered with Mitsuba 3 (analytic materials, and the expanded tables for a few scenes), passed
   through the camera model (four raw HDR brackets with noise, written as capture folders)
   (:func:`blender_addon.core.generate.generate`).
3. ``decode``: each raw capture folder goes through the real-capture path (HDR merge,
   demosaic, Stokes, nine maps: :func:`pbrdf.data.capture_decode.decode_capture`).
4. ``infer``: the shipped model predicts normal, albedo, roughness and metallic
   (:func:`network.infer.predict`).
5. ``evaluate``: metrics against the ground truth and against the classical RGB
   photometric-stereo baseline (:mod:`network.evaluation`).
6. ``blender``: the predictions are imported into Blender (bpy wheel) as Principled BSDF assets
   and relit under a rotating point light and an environment map with Cycles. bpy never shares a
   process with torch: each asset runs ``headless/relight.py`` (over
   ``blender_addon.relight_job``) in its own process, so this module imports no bpy.
7. ``report``: figures, ``metrics.json``, ``metrics.md``, ``timings.json`` and ``report.html``
   (:mod:`network.demo.report`).

Example:
    >>> DemoConfig(scenes=2, measured_scenes=1).measured_scenes
    1
    >>> DemoConfig(scenes=1, measured_scenes=2)
    Traceback (most recent call last):
    ...
    ValueError: need scenes >= 1 and 0 <= measured_scenes <= scenes; got 1, 2
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from network.demo import figures as scene_figs
from network.demo import report
from network.demo.relight_compare import compare_relit, relight, truth_maps
from pbrdf.io.strict_json import dumps_strict

__all__ = ["DemoConfig", "run_demo"]

#: Generated pBRDF tables drawn in ``pbrdfs/figure_generated.png`` (the seed figure shows every seed).
FIGURE_TABLES = 8


@dataclass(frozen=True)
class DemoConfig:
    """Sizes of the demo (the flags of ``headless/demo.py``).

    Attributes:
        out: output folder.
        scenes: scenes to render.
        measured_scenes: of which rendered with expanded pBRDF tables.
        resolution: map size in pixels (square).
        spp: samples per pixel per colour pass.
        tables: expanded pBRDF tables to generate.
        checkpoint: model to run; None for the shipped model.
        relight_frames: point-light orbit frames per asset (0: no relit frames).
        relight_size: longest side of a relit frame in pixels.
        relight_samples: Cycles samples per pixel.
        seed: seed of every stage.
        blender: run the Blender import and relighting stage.
        progress: show progress bars.

    Raises:
        ValueError: inconsistent or out-of-range sizes.
    """

    out: Path = Path("out/demo")
    scenes: int = 6
    measured_scenes: int = 2
    resolution: int = 128
    spp: int = 16
    tables: int = 6
    checkpoint: Path | None = None
    relight_frames: int = 6
    relight_size: int = 256
    relight_samples: int = 32
    seed: int = 0
    blender: bool = True
    progress: bool = True

    def __post_init__(self) -> None:
        if self.scenes < 1 or not 0 <= self.measured_scenes <= self.scenes:
            raise ValueError(f"need scenes >= 1 and 0 <= measured_scenes <= scenes; got {self.scenes}, "
                             f"{self.measured_scenes}")  # fmt: skip
        if self.resolution < 16 or self.spp < 1 or self.tables < 1 or self.relight_frames < 0:
            raise ValueError("resolution >= 16, spp >= 1, tables >= 1 and relight_frames >= 0 are required")


@dataclass
class _Timer:
    """Wall-clock seconds per stage, accumulated by :meth:`stage`."""

    seconds: dict[str, float] = field(default_factory=dict)

    @contextmanager
    def stage(self, name: str):
        """Context manager adding the block's wall time to ``seconds[name]``."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - t0


def _bar(total: int, desc: str, enabled: bool):
    """A tqdm progress bar (disabled unless ``enabled``)."""
    from tqdm import tqdm  # noqa: PLC0415

    return tqdm(total=total, desc=desc, unit="item", disable=not enabled, leave=False)


def _samples(root: Path) -> list[Path]:
    """The sample sidecars of a dataset folder, in index order."""
    return sorted((root / "samples").glob("*.json"))


def run_demo(cfg: DemoConfig, render_dataset: Callable[..., Any]) -> dict:
    """Run every stage and write the report.

    Args:
        cfg: the demo's sizes and output folder.
        render_dataset: renders a dataset with raw brackets: called as ``render_dataset(out=...,
            count=..., resolution=..., spp=..., seed=..., pbrdfs=..., progress=...)`` and returns a
            report with ``failed`` (``{index: reason}``). The caller supplies it
            (``headless/demo.py`` wraps ``blender_addon.core.generate``), so ``network`` never
            imports the scene side.

    Returns:
        The summary also written to ``OUT/metrics.json``: ``config``, ``checkpoint``, ``inputs``,
        ``mean`` (mask-weighted means per method), ``scenes`` (one row per scene),
        ``timings_s`` (seconds per stage) and ``pbrdf_expansion``.

    Raises:
        RuntimeError: a sample failed to render or a relighting process failed.
        ValueError, OSError: from the stages (bad checkpoint, unwritable folder).
    """
    from network.checkpoint import load_checkpoint  # noqa: PLC0415
    from network.constant import load_statistics  # noqa: PLC0415
    from network.evaluation import predict_scene, score_scene  # noqa: PLC0415
    from network.infer import DEFAULT_CHECKPOINT  # noqa: PLC0415
    from pbrdf.expansion.run import ExpansionConfig, run_expansion  # noqa: PLC0415
    from pbrdf.io.atomic import atomic_write_text  # noqa: PLC0415

    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    fig_dir = out / "figures"
    timer = _Timer()
    ckpt_path = Path(cfg.checkpoint) if cfg.checkpoint else DEFAULT_CHECKPOINT
    stages = ["pbrdf", "render", "decode", "infer", "evaluate", "blender", "report"]
    from tqdm import tqdm  # noqa: PLC0415

    overall = tqdm(total=len(stages), desc="demo", unit="stage", disable=not cfg.progress)

    def step(name: str) -> None:
        overall.set_postfix_str(name)

    # 1. pBRDF expansion from the built-in seeds.
    step("pbrdf")
    with timer.stage("pbrdf expansion"):
        exp = run_expansion(
            ExpansionConfig(
                out=out / "pbrdfs", count=cfg.tables, seed=cfg.seed, generator_steps=300, figures=FIGURE_TABLES
            ),  # fmt: skip
            progress=cfg.progress,
        )
    overall.update()

    # 2. Scenes, polarized rendering, camera model (raw brackets kept as capture folders).
    step("render")
    with timer.stage("render (Mitsuba + camera model)"):
        analytic = cfg.scenes - cfg.measured_scenes
        reports = []
        if analytic:
            reports.append(render_dataset(
                out=out / "data" / "analytic", count=analytic, resolution=cfg.resolution, spp=cfg.spp,
                seed=cfg.seed, pbrdfs=None, progress=cfg.progress))  # fmt: skip
        if cfg.measured_scenes:
            reports.append(render_dataset(
                out=out / "data" / "measured", count=cfg.measured_scenes, resolution=cfg.resolution, spp=cfg.spp,
                seed=cfg.seed + 1, pbrdfs=out / "pbrdfs", progress=cfg.progress))  # fmt: skip
        failed = {k: v for r in reports for k, v in r.failed.items()}
        if failed:
            raise RuntimeError(f"rendering failed for samples {failed}")
    samples = [p for sub in ("analytic", "measured") for p in _samples(out / "data" / sub)]
    overall.update()

    # 3-4. Every raw capture folder through the user's path (decode, automatic foreground mask),
    # then the shipped model, the photometric-stereo baseline and the constant predictor.
    step("infer")
    model, ckpt = load_checkpoint(ckpt_path)
    variant = ckpt.get("inputs", "full")
    stats = load_statistics(_stats_path(cfg, ckpt_path))
    scenes, names = {}, {}
    with timer.stage("capture path: decode, mask, model, baselines"):
        bar = _bar(len(samples), "predict", cfg.progress)
        for s in samples:
            name = f"{s.parent.parent.name}_{s.stem}"
            scene = predict_scene(model, variant, s.parent.parent, int(s.stem), stats, input_scale=ckpt["input_scale"])
            if scene.ours is not None:
                _write_assets(out, name, scene)
            scenes[s], names[s] = scene, name
            bar.update()
        bar.close()
    overall.update()
    overall.update()  # the decode stage is part of the capture path above

    # 5. Metrics against the ground truth, on the object coverage.
    step("evaluate")
    rows, figures = [], []
    with timer.stage("evaluate"):
        bar = _bar(len(samples), "evaluate", cfg.progress)
        for s in samples:
            scene = scenes[s]
            row = score_scene(scene, lpips=True)
            kind = next(iter(scene.meta["materials"].values()))["kind"]
            rows.append({"scene": names[s], "material": kind, **row})
            figures += scene_figs.scene_figures(
                fig_dir, names[s], scene.maps, scene.region, scene.gt, scene.preds["ours"], scene.preds["baseline"]
            )
            bar.update()
        bar.close()
    overall.update()

    # 6. Blender: import the predictions as Principled BSDF assets and relight them with Cycles.
    step("blender")
    relit: list[tuple[str, str]] = []
    relight_rows: list[dict] = []
    blender_note = ""
    if cfg.blender:
        with timer.stage("Blender import + Cycles relight"):
            bar = _bar(len(samples), "relight", cfg.progress)
            for s in samples:  # one Blender process per asset: bpy never shares a process with torch
                name = names[s]
                if scenes[s].ours is None:
                    continue
                kw = {"frames": cfg.relight_frames, "size": cfg.relight_size, "samples": cfg.relight_samples}
                frames = relight(out / "predictions" / name, name, out / "relit" / name, **kw)
                truth = relight(out / "truth" / name, name, out / "relit_truth" / name, **kw)
                if frames:
                    scores = compare_relit(frames, truth)
                    relight_rows.append({"scene": name, "frames": scores, **_mean_scores(scores)})
                    fig, caption = scene_figs.relit_figure(fig_dir / f"{name}_relit.png", name, truth, frames, scores)
                    relit.append((fig.relative_to(out).as_posix(), caption))
                bar.update()
            bar.close()
    else:
        blender_note = "Blender stage skipped (--no-blender)."
    overall.update()

    # 7. Report.
    step("report")
    with timer.stage("report"):
        summary = _write_outputs(
            out, cfg, rows, figures, (relit, relight_rows), timer, exp, ckpt_path, variant, blender_note
        )
    overall.update()
    overall.close()
    atomic_write_text(out / "timings.json", dumps_strict(timer.seconds) + "\n")
    return summary


def _write_assets(out: Path, name: str, scene) -> None:
    """The prediction (with its relief) and the truth, as the Blender import reads them.

    Both carry the capture's camera; the prediction's relief is anchored at the true median depth
    (the distance a user measures), since the rendered capture has no ``distance_m``.
    """
    from network.infer import camera_record, relief_depth, write_predictions  # noqa: PLC0415

    truth = truth_maps(scene.gt, scene.region)
    distance = float(np.median(truth["depth"][scene.region, 0])) if "depth" in truth else None
    camera = None
    pred = dict(scene.ours)
    if scene.intrinsics is not None:
        camera = camera_record(scene.intrinsics, scene.region.shape, distance)
        pred["depth"] = relief_depth(pred, scene.intrinsics, distance)
    write_predictions(out / "predictions" / name, name, pred, camera)
    write_predictions(out / "truth" / name, name, truth, camera)


def _expansion_figures(out: Path) -> list[tuple[str, str]]:
    """The expansion's figures that exist under ``out/pbrdfs``, each with its caption."""
    from pbrdf.expansion import figures as exp_figures  # noqa: PLC0415
    from pbrdf.io.strict_json import loads_strict  # noqa: PLC0415

    manifest = loads_strict((out / "pbrdfs" / "manifest.json").read_text())
    counts = {"figure_seeds.png": len(manifest["seeds"]), "figure_generated.png": min(manifest["count"], FIGURE_TABLES)}
    return [(f"pbrdfs/{name}", exp_figures.caption(name, n)) for name, n in counts.items()
            if (out / "pbrdfs" / name).is_file()]  # fmt: skip


def _mean_scores(scores: list[dict]) -> dict[str, float | None]:
    out = {}
    for key in ("psnr", "lpips"):
        vals = [s[key] for s in scores if s[key] is not None]
        out[key] = float(np.mean(vals)) if vals else None
    return out


def _deg(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.1f} deg"


def _stats_path(cfg: DemoConfig, ckpt_path: Path) -> Path:
    """Training statistics for the constant row: beside the checkpoint, else the shipped model's."""
    from network.constant import STATS_FILE  # noqa: PLC0415
    from network.infer import DEFAULT_CHECKPOINT  # noqa: PLC0415

    beside = Path(ckpt_path).parent / STATS_FILE
    return beside if beside.is_file() else Path(DEFAULT_CHECKPOINT).parent / STATS_FILE


def _write_outputs(out, cfg, rows, figures, relit, timer, exp, ckpt_path, variant, blender_note) -> dict:
    """Write metrics.json, metrics.md, the charts and report.html; returns the summary."""
    relit, relight_rows = relit
    from network.evaluation import model_label, results_markdown, summarize_rows, summary_table  # noqa: PLC0415
    from pbrdf.io.atomic import atomic_write_text  # noqa: PLC0415
    from pbrdf.io.strict_json import dumps_strict  # noqa: PLC0415

    fig_dir = out / "figures"
    result = {"split": "demo scenes", "data": str(out / "data"), "scenes": len(rows), "lpips": True,
              "model": model_label(ckpt_path),
              "description": "the demo's scenes through the real-capture path (raw brackets, decode, automatic "
                             "mask), scored on the object coverage",
              **summarize_rows(rows)}  # fmt: skip
    header, table = summary_table(result)
    means = {m: {k: v["mean"] for k, v in result["methods"][m].items()} for m in ("baseline", "constant", "ours")}
    per_scene_header = ["scene", "material", "mask IoU", "normal MAE ours", "normal MAE baseline",
                        "normal MAE constant", "albedo si-PSNR ours", "roughness RMSE ours",
                        "roughness RMSE constant", "metallic RMSE ours"]  # fmt: skip
    per_scene = [[r["scene"], r["material"], r["mask_iou"], r["ours"]["normal_mae"], r["baseline"]["normal_mae"],
                  r["constant"]["normal_mae"], r["ours"]["albedo_si_psnr"], r["ours"]["roughness_rmse"],
                  r["constant"]["roughness_rmse"], r["ours"]["metallic_rmse"]] for r in rows]  # fmt: skip
    chart = report.metric_chart(
        fig_dir / "metrics.png",
        {"baseline (PS)": means["baseline"], "constant": means["constant"], "ours": means["ours"]},
        [("normal_mae", "normal MAE (deg)", True), ("albedo_si_psnr", "albedo si-PSNR (dB)", False),
         ("roughness_rmse", "roughness RMSE", True), ("metallic_rmse", "metallic RMSE", True)],
    )  # fmt: skip
    timing = report.timing_chart(fig_dir / "timings.png", timer.seconds)
    summary = {
        "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()},
        "checkpoint": str(ckpt_path),
        "inputs": variant,
        "mean": means,
        "methods": result["methods"],
        "mask_iou": result["mask_iou"],
        "scenes": rows,
        "timings_s": timer.seconds,
        "pbrdf_expansion": exp.summary(),
        "relight": relight_rows,
    }
    atomic_write_text(out / "metrics.json", dumps_strict(summary) + "\n")
    md = "# Demo metrics\n\n" + results_markdown(result) + "\n## Per scene\n\n"
    md += report.markdown_table(per_scene_header, per_scene)
    relight_header = ["scene", "relit PSNR (dB)", "relit LPIPS"]
    relight_table = [[r["scene"], r["psnr"], r["lpips"]] for r in relight_rows]
    if relight_rows:
        md += "\n## Relit prediction against the relit truth\n\n" + report.markdown_table(relight_header, relight_table)
    md += "\n## Time per stage (s)\n\n" + report.markdown_table(["stage", "seconds"], list(timer.seconds.items()))
    atomic_write_text(out / "metrics.md", md)
    ours_mae, base_mae, const_mae = (means[m]["normal_mae"] for m in ("ours", "baseline", "constant"))
    exp_figs = _expansion_figures(out)
    sections = [
        {
            "title": "Summary",
            "text": (
                f"{len(rows)} synthetic scenes ({cfg.resolution}x{cfg.resolution} maps, {cfg.spp} spp per colour pass) "
                f"were rendered with Mitsuba 3 under the polarized RGB display, captured through the camera model as "
                f"four noisy 12-bit raw brackets, decoded into the nine maps, and reconstructed by the shipped model "
                f"({ckpt_path.name}, inputs '{variant}') from the automatic foreground mask, exactly as a user's "
                f"capture is processed. Mean normal error on the object coverage: ours {_deg(ours_mae)}, "
                f"photometric stereo {_deg(base_mae)}, the constant normal facing the camera {_deg(const_mae)}. "
                + blender_note
            ),
        },  # fmt: skip
        {
            "title": "Metrics (per-scene means with 95 % bootstrap intervals, object coverage)",
            "html": report.html_table(header, table),
            "figures": [
                (
                    chart.relative_to(out).as_posix(),
                    "Mean over the scenes of each metric (one panel each; its title says whether lower or higher "
                    "is better) for our model, the classical photometric-stereo baseline (PS) and the constant "
                    "predictor from the training-set statistics; the number above a bar is its value, n/a where "
                    "a method does not predict that map. The table above gives the 95 % intervals.",
                )
            ],
        },
        {"title": "Per scene", "html": report.html_table(per_scene_header, per_scene)},
        {
            "title": "Inputs, predictions, ground truth and errors",
            "text": (
                "Per scene, two figures: the decoded input maps, then the predictions beside the ground truth, the "
                "photometric-stereo baseline and the error maps. Each caption says how its colours read; normals "
                "use x right = red, y up = green, z toward the camera = blue, with a key in the figure."
            ),
            "figures": figures,
        },
        {
            "title": "Relighting in Blender: prediction against truth",
            "figures": relit,
            "text": (
                "Both map sets go through the same import (relief mesh from the depth, the capture's camera) and "
                "the same Cycles lights; scores are over the pixels either asset covers. The prediction's relief "
                "is anchored at the true median depth, the distance a user enters as distance_m."
                if relit
                else "No relit frames (Blender stage skipped)."
            ),
            "html": report.html_table(relight_header, relight_table) if relight_rows else "",
        },
        {
            "title": "Expanded pBRDFs",
            "text": (
                f"The analytic seed materials are factorised, compressed by PCA and modelled by a conditional "
                f"generator; {cfg.tables} new tables were drawn from it, filtered for physical validity and labelled "
                f"with their Disney fit ({cfg.measured_scenes} scene(s) above use them). The spheres show what each "
                f"material does to light; the captions say how to read the three panels."
            ),
            "figures": exp_figs,
        },
        {
            "title": "Time per stage",
            "figures": [
                (
                    timing.relative_to(out).as_posix(),
                    "Wall-clock seconds of each demo stage on this machine, in pipeline order (the total in the "
                    "title); the table below has the same numbers.",
                )
            ],
            "html": report.html_table(["stage", "seconds"], [[k, v] for k, v in timer.seconds.items()]),
        },
    ]
    report.write_report(out / "report.html", "Snapshot polarimetric display inverse rendering: demo", sections)
    return summary
