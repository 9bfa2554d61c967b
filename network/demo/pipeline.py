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
   process with torch: every asset is relit by one ``headless/relight.py --jobs`` process (over
   ``blender_addon.relight_job``), so this module imports no bpy.
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

#: The stages in order (the overall progress bar; ``decode`` runs inside ``infer``'s capture path).
STAGES = ("pbrdf", "render", "decode", "infer", "evaluate", "blender", "report")

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
        relight_denoise: Cycles' denoiser on the relit frames.
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
    relight_size: int = 128
    relight_samples: int = 4
    relight_denoise: bool = True
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


@contextmanager
def _stage(overall, name: str, stages: int = 1):
    """Show ``name`` on the overall bar; advance it by ``stages`` when the block succeeds."""
    overall.set_postfix_str(name)
    yield
    overall.update(stages)


@dataclass
class _Results:
    """What the scoring stages produce for the report.

    Attributes:
        rows: one row per scene (``network.evaluation.score_scene`` plus ``scene``, ``material``).
        figures: the per-scene figures, ``(path, caption)``.
        relit: the relighting figures, ``(path relative to out, caption)``.
        relight_rows: relit prediction against relit truth per scene (``psnr``, ``lpips``, ``frames``, and
            ``constant``: the relit constant predictor's ``psnr`` and ``lpips``).
        blender_note: a sentence for the summary when the Blender stage was skipped.
    """

    rows: list[dict] = field(default_factory=list)
    figures: list[tuple[str, str]] = field(default_factory=list)
    relit: list[tuple[str, str]] = field(default_factory=list)
    relight_rows: list[dict] = field(default_factory=list)
    blender_note: str = ""


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
    from tqdm import tqdm  # noqa: PLC0415

    from network.checkpoint import load_checkpoint  # noqa: PLC0415
    from network.infer import DEFAULT_CHECKPOINT  # noqa: PLC0415
    from pbrdf.io.atomic import atomic_write_text  # noqa: PLC0415

    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    timer = _Timer()
    ckpt_path = Path(cfg.checkpoint) if cfg.checkpoint else DEFAULT_CHECKPOINT
    overall = tqdm(total=len(STAGES), desc="demo", unit="stage", disable=not cfg.progress)
    with _stage(overall, "pbrdf"), timer.stage("pbrdf expansion"):
        expansion = _expand_pbrdfs(cfg, out)
    with _stage(overall, "render"), timer.stage("render (Mitsuba + camera model)"):
        _render(cfg, out, render_dataset)
    samples = [p for sub in ("analytic", "measured") for p in _samples(out / "data" / sub)]
    with _stage(overall, "infer", 2):  # the decode stage is part of the capture path
        model, ckpt = load_checkpoint(ckpt_path)
        variant = ckpt.get("inputs", "full")
        with timer.stage("capture path: decode, mask, model, baselines"):
            scenes = _predict(cfg, out, samples, model, ckpt, _stats_path(ckpt_path))
    with _stage(overall, "evaluate"), timer.stage("evaluate"):
        results = _evaluate(cfg, out, scenes)
    with _stage(overall, "blender"):
        if cfg.blender:
            with timer.stage("Blender import + Cycles relight"):
                _relight(cfg, out, scenes, results)
        else:
            results.blender_note = "Blender stage skipped (--no-blender)."
    with _stage(overall, "report"), timer.stage("report"):
        summary = _write_outputs(out, cfg, results, timer, expansion, ckpt_path, variant)
    overall.close()
    atomic_write_text(out / "timings.json", dumps_strict(timer.seconds) + "\n")
    return summary


def _expand_pbrdfs(cfg: DemoConfig, out: Path):
    """Stage 1: expand the built-in seeds into ``cfg.tables`` new pBRDF tables under ``out/pbrdfs``."""
    from pbrdf.expansion.run import ExpansionConfig, run_expansion  # noqa: PLC0415

    exp_cfg = ExpansionConfig(out=out / "pbrdfs", count=cfg.tables, seed=cfg.seed, generator_steps=300,
                              figures=FIGURE_TABLES)  # fmt: skip
    return run_expansion(exp_cfg, progress=cfg.progress)


def _render(cfg: DemoConfig, out: Path, render_dataset: Callable[..., Any]) -> None:
    """Stage 2: scenes, polarized rendering, camera model (raw brackets kept as capture folders)."""
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


def _predict(cfg: DemoConfig, out: Path, samples: list[Path], model, ckpt: dict, stats_path: Path) -> dict:
    """Stages 3-4: every raw capture folder through the user's path, then the model and the baselines.

    Decode, automatic foreground mask, the shipped model, the photometric-stereo baseline and the
    constant predictor (:func:`network.evaluation.predict_scene`); the prediction and the truth are
    written for the Blender import.

    Returns:
        ``{name: scene}`` in sample order, ``name`` = ``<dataset>_<index>``.
    """
    from network.constant import load_statistics  # noqa: PLC0415
    from network.evaluation import predict_scene  # noqa: PLC0415

    variant, stats = ckpt.get("inputs", "full"), load_statistics(stats_path)
    scenes = {}
    bar = _bar(len(samples), "predict", cfg.progress)
    for s in samples:
        name = f"{s.parent.parent.name}_{s.stem}"
        scene = predict_scene(model, variant, s.parent.parent, int(s.stem), stats, input_scale=ckpt["input_scale"])
        if scene.ours is not None:
            _write_assets(out, name, scene)
        scenes[name] = scene
        bar.update()
    bar.close()
    return scenes


def _evaluate(cfg: DemoConfig, out: Path, scenes: dict) -> _Results:
    """Stage 5: metrics against the ground truth on the object coverage, and the per-scene figures."""
    from network.evaluation import score_scene  # noqa: PLC0415

    results = _Results()
    bar = _bar(len(scenes), "evaluate", cfg.progress)
    for name, scene in scenes.items():
        row = score_scene(scene, lpips=True)
        kind = next(iter(scene.meta["materials"].values()))["kind"]
        results.rows.append({"scene": name, "material": kind, **row})
        results.figures += scene_figs.scene_figures(
            out / "figures", name, scene.maps, scene.region, scene.gt, scene.preds["ours"], scene.preds["baseline"]
        )
        bar.update()
    bar.close()
    return results


def _relight(cfg: DemoConfig, out: Path, scenes: dict, results: _Results) -> None:
    """Stage 6: import prediction, truth and constant predictor as Principled BSDF assets, relight them, compare.

    One Blender process for every asset (bpy never shares a process with torch; it starts once).
    """
    kw = {"frames": cfg.relight_frames, "size": cfg.relight_size, "samples": cfg.relight_samples,
          "denoise": cfg.relight_denoise}  # fmt: skip
    names = [name for name, scene in scenes.items() if scene.ours is not None]
    kinds = (("predictions", "relit", True), ("truth", "relit_truth", True), ("constant", "relit_constant", False))
    assets = [(out / src / name, name, out / dest / name, blend) for name in names for src, dest, blend in kinds]
    bar = _bar(len(assets), "relight", cfg.progress)
    relit = relight(assets, **kw, on_done=lambda _: bar.update()) if assets else []
    bar.close()
    for i, name in enumerate(names):
        frames, truth, constant = relit[3 * i : 3 * i + 3]
        if frames:
            scores = compare_relit(frames, truth)
            const = _mean_scores(compare_relit(constant, truth))
            results.relight_rows.append({"scene": name, "frames": scores, **_mean_scores(scores), "constant": const})
            fig, caption = scene_figs.relit_figure(out / "figures" / f"{name}_relit.png", name, truth, frames, scores)
            results.relit.append((fig.relative_to(out).as_posix(), caption))


def _write_assets(out: Path, name: str, scene) -> None:
    """The prediction (with its relief), the truth and the constant predictor, as the Blender import reads them.

    All carry the capture's camera; the prediction's relief is anchored at the true median depth
    (the distance a user measures), since the rendered capture has no ``distance_m``. The constant
    predictor (its normal faces the camera: a flat relief at that depth) is relit alike, so a relit
    PSNR of the prediction has a floor to read it against.
    """
    from network.infer import relief_depth  # noqa: PLC0415
    from pbrdf.data.predictions import CameraRecord, write_predictions  # noqa: PLC0415

    truth = truth_maps(scene.gt, scene.region)
    distance = float(np.median(truth["depth"][scene.region, 0])) if "depth" in truth else None
    camera = None
    pred = dict(scene.ours)
    if scene.intrinsics is not None:
        camera = CameraRecord.of_maps(scene.intrinsics, scene.region.shape, distance)
        pred["depth"] = relief_depth(pred, scene.intrinsics, distance)
    write_predictions(out / "predictions" / name, name, pred, camera)
    write_predictions(out / "truth" / name, name, truth, camera)
    # the constant maps over the prediction's own mask (the same coverage: only the maps differ)
    inside = pred["mask"][..., 0] > 0
    constant = {k: np.where(inside[..., None], np.asarray(v)[scene.region][0], 0.0).astype(np.float32)
                for k, v in scene.preds["constant"].items()}  # fmt: skip
    constant["mask"] = pred["mask"]
    if scene.intrinsics is not None:
        constant["depth"] = relief_depth(constant, scene.intrinsics, distance)
    write_predictions(out / "constant" / name, name, constant, camera)


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


def _stats_path(ckpt_path: Path) -> Path:
    """Training statistics for the constant row: beside the checkpoint, else the shipped model's."""
    from network.constant import STATS_FILE  # noqa: PLC0415
    from network.infer import DEFAULT_CHECKPOINT  # noqa: PLC0415

    beside = Path(ckpt_path).parent / STATS_FILE
    return beside if beside.is_file() else Path(DEFAULT_CHECKPOINT).parent / STATS_FILE


#: The per-scene table of metrics.md and report.html.
PER_SCENE_HEADER = ("scene", "material", "mask IoU", "normal MAE ours", "normal MAE baseline",
                    "normal MAE constant", "albedo si-PSNR ours", "roughness RMSE ours", "roughness RMSE constant",
                    "metallic RMSE ours")  # fmt: skip
RELIGHT_HEADER = ("scene", "relit PSNR (dB)", "relit LPIPS", "constant relit PSNR (dB)", "constant relit LPIPS")


def _relight_table(rows: list[dict]) -> list[list]:
    """The relighting table's rows (columns: :data:`RELIGHT_HEADER`)."""
    return [[r["scene"], r["psnr"], r["lpips"], r["constant"]["psnr"], r["constant"]["lpips"]] for r in rows]


def _per_scene(rows: list[dict]) -> list[list]:
    """The per-scene table's rows (columns: :data:`PER_SCENE_HEADER`)."""
    return [[r["scene"], r["material"], r["mask_iou"], r["ours"]["normal_mae"], r["baseline"]["normal_mae"],
             r["constant"]["normal_mae"], r["ours"]["albedo_si_psnr"], r["ours"]["roughness_rmse"],
             r["constant"]["roughness_rmse"], r["ours"]["metallic_rmse"]] for r in rows]  # fmt: skip


def _write_outputs(out: Path, cfg: DemoConfig, results: _Results, timer: _Timer, expansion, ckpt_path: Path,
                   variant: str) -> dict:  # fmt: skip
    """Stage 7: write metrics.json, metrics.md, the charts and report.html; returns the summary.

    Args:
        out: the demo's output folder.
        cfg: the demo's sizes.
        results: the scored scenes (and the relighting's, if it ran).
        timer: seconds per stage so far.
        expansion: the pBRDF expansion's result (its ``summary()`` goes into metrics.json).
        ckpt_path: the model that ran.
        variant: its input variant.

    Returns:
        The summary written to ``metrics.json`` (see :func:`run_demo`).
    """
    from network.evaluation import model_label, summarize_rows  # noqa: PLC0415
    from pbrdf.io.atomic import atomic_write_text  # noqa: PLC0415

    result = {"split": "demo scenes", "data": str(out / "data"), "scenes": len(results.rows), "lpips": True,
              "model": model_label(ckpt_path),
              "description": "the demo's scenes through the real-capture path (raw brackets, decode, automatic "
                             "mask), scored on the object coverage",
              **summarize_rows(results.rows)}  # fmt: skip
    means = {m: {k: v["mean"] for k, v in result["methods"][m].items()} for m in ("baseline", "constant", "ours")}
    summary = {
        "config": {k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(cfg).items()},
        "checkpoint": str(ckpt_path),
        "inputs": variant,
        "mean": means,
        "methods": result["methods"],
        "mask_iou": result["mask_iou"],
        "scenes": results.rows,
        "timings_s": timer.seconds,
        "pbrdf_expansion": expansion.summary(),
        "relight": results.relight_rows,
    }
    atomic_write_text(out / "metrics.json", dumps_strict(summary) + "\n")
    atomic_write_text(out / "metrics.md", _metrics_markdown(result, results, timer))
    summary_text = _summary_text(cfg, results, means, ckpt_path, variant)
    sections = [
        {"title": "Summary", "text": summary_text},
        _metrics_section(out, result, means),
        {"title": "Per scene", "html": report.html_table(PER_SCENE_HEADER, _per_scene(results.rows))},
        *_figure_sections(out, cfg, results),
        _timing_section(out, timer),
    ]
    report.write_report(out / "report.html", "Snapshot polarimetric display inverse rendering: demo", sections)
    return summary


def _metrics_markdown(result: dict, results: _Results, timer: _Timer) -> str:
    """metrics.md: the split table, the per-scene table, the relighting scores and the time per stage."""
    from network.evaluation import results_markdown  # noqa: PLC0415

    md = "# Demo metrics\n\n" + results_markdown(result) + "\n## Per scene\n\n"
    md += report.markdown_table(PER_SCENE_HEADER, _per_scene(results.rows))
    if results.relight_rows:
        md += "\n## Relit prediction (and the constant predictor) against the relit truth\n\n"
        md += report.markdown_table(RELIGHT_HEADER, _relight_table(results.relight_rows))
    md += "\n## Time per stage (s)\n\n" + report.markdown_table(["stage", "seconds"], list(timer.seconds.items()))
    return md


def _summary_text(cfg: DemoConfig, results: _Results, means: dict, ckpt_path: Path, variant: str) -> str:
    """The report's opening paragraph: what ran and the mean normal errors."""
    ours_mae, base_mae, const_mae = (means[m]["normal_mae"] for m in ("ours", "baseline", "constant"))
    return (
        f"{len(results.rows)} synthetic scenes ({cfg.resolution}x{cfg.resolution} maps, {cfg.spp} spp per colour "
        f"pass) were rendered with Mitsuba 3 under the polarized RGB display, captured through the camera model as "
        f"four noisy 12-bit raw brackets, decoded into the nine maps, and reconstructed by the shipped model "
        f"({ckpt_path.name}, inputs '{variant}') from the automatic foreground mask, exactly as a user's "
        f"capture is processed. Mean normal error on the object coverage: ours {_deg(ours_mae)}, "
        f"photometric stereo {_deg(base_mae)}, the constant normal facing the camera {_deg(const_mae)}. "
        + results.blender_note
    )


def _metrics_section(out: Path, result: dict, means: dict) -> dict:
    """The report's metrics table with its chart (``figures/metrics.png``)."""
    from network.evaluation import summary_table  # noqa: PLC0415

    header, table = summary_table(result)
    chart = report.metric_chart(
        out / "figures" / "metrics.png",
        {"baseline (PS)": means["baseline"], "constant": means["constant"], "ours": means["ours"]},
        [("normal_mae", "normal MAE (deg)", True), ("albedo_si_psnr", "albedo si-PSNR (dB)", False),
         ("roughness_rmse", "roughness RMSE", True), ("metallic_rmse", "metallic RMSE", True)],
    )  # fmt: skip
    caption = (
        "Mean over the scenes of each metric (one panel each; its title says whether lower or higher "
        "is better) for our model, the classical photometric-stereo baseline (PS) and the constant "
        "predictor from the training-set statistics; the number above a bar is its value, n/a where "
        "a method does not predict that map. The table above gives the 95 % intervals."
    )
    return {
        "title": "Metrics (per-scene means with 95 % bootstrap intervals, object coverage)",
        "html": report.html_table(header, table),
        "figures": [(chart.relative_to(out).as_posix(), caption)],
    }


def _figure_sections(out: Path, cfg: DemoConfig, results: _Results) -> list[dict]:
    """The report's figure sections: per-scene maps, relighting, expanded pBRDFs."""
    relight_table = _relight_table(results.relight_rows)
    return [
        {
            "title": "Inputs, predictions, ground truth and errors",
            "text": (
                "Per scene, two figures: the decoded input maps, then the predictions beside the ground truth, the "
                "photometric-stereo baseline and the error maps. Each caption says how its colours read; normals "
                "use x right = red, y up = green, z toward the camera = blue, with a key in the figure."
            ),
            "figures": results.figures,
        },
        {
            "title": "Relighting in Blender: prediction against truth",
            "figures": results.relit,
            "text": (
                "Both map sets go through the same import (relief mesh from the depth, the capture's camera) and "
                "the same Cycles lights; scores are over the pixels either asset covers. The prediction's relief "
                "is anchored at the true median depth, the distance a user enters as distance_m. The constant "
                "predictor (normal facing the camera, the training set's mean albedo, roughness and metallic) is "
                "relit the same way: its relit PSNR is what a prediction's must beat to mean anything."
                if results.relit
                else "No relit frames (Blender stage skipped)."
            ),
            "html": report.html_table(RELIGHT_HEADER, relight_table) if results.relight_rows else "",
        },
        {
            "title": "Expanded pBRDFs",
            "text": (
                f"The analytic seed materials are factorised, compressed by PCA and modelled by a conditional "
                f"generator; {cfg.tables} new tables were drawn from it, filtered for physical validity and labelled "
                f"with their Disney fit ({cfg.measured_scenes} scene(s) above use them). The spheres show what each "
                f"material does to light; the captions say how to read the three panels."
            ),
            "figures": _expansion_figures(out),
        },
    ]


def _timing_section(out: Path, timer: _Timer) -> dict:
    """The report's time-per-stage chart (``figures/timings.png``) and table."""
    timing = report.timing_chart(out / "figures" / "timings.png", timer.seconds)
    caption = (
        "Wall-clock seconds of each demo stage on this machine, in pipeline order (the total in the "
        "title); the table below has the same numbers."
    )
    return {
        "title": "Time per stage",
        "figures": [(timing.relative_to(out).as_posix(), caption)],
        "html": report.html_table(["stage", "seconds"], [[k, v] for k, v in timer.seconds.items()]),
    }
