"""The paper's Table 3 at this machine's scale: input variants and pBRDF sources, one budget, one command.

Six runs (:data:`RUNS`) train the same model configuration with the same steps, batch, learning
rate and seed on the same number of scenes of the data engine; only what the network sees, or the
materials it learns from, changes:

============  =====================  ==========  ==========================================
run           training data          inputs      scenes (``scenes`` of them)
============  =====================  ==========  ==========================================
``white``     train-engine-white     white       the first ones (the same scenes, white display)
``spectral``  train-engine           spectral    the first ones
``polar``     train-engine           polar       the first ones
``full``      train-engine           full        the first ones
``analytic``  train-engine           full        the first whose objects are all analytic
``expanded``  train-engine           full        the first whose objects are all expanded tables
============  =====================  ==========  ==========================================

Every run is scored on the ``test-scenes`` split (``white`` on its twin ``test-scenes-white``:
the same scenes under a white display) through the real-capture path
(:func:`network.evaluation.evaluate_dataset`: raw brackets, decode, automatic mask), with 95 %
bootstrap intervals over scenes, next to the constant predictor and the photometric-stereo
baseline. No run reads validation or test data while training (the last step is scored), so the
runs differ in nothing but the ablated factor.

Training resumes (:func:`network.train.train` with ``resume``): a killed ablation continues
where it stopped, and finished runs are not trained again. :func:`trend_lines` checks the
paper's two trends (spectral multiplexing lowers normal MAE most; circular polarization lowers
metallic RMSE most) and says when one does not appear.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pbrdf.data import dataset as pdataset
from pbrdf.data import sample as psample
from pbrdf.io.atomic import atomic_write_text
from pbrdf.io.strict_json import dumps_strict

from .compare import paired_gain

__all__ = [
    "DEFAULT_OVERRIDES",
    "RUNS",
    "AblationConfig",
    "ablation_markdown",
    "evaluate_runs",
    "run_ablation",
    "run_indices",
    "scene_kind",
    "train_runs",
    "trend_lines",
]


@dataclass(frozen=True)
class Run:
    """One row of the ablation: training split, input variant and which scenes."""

    name: str
    data: str
    inputs: str
    scenes: str  # "first", "analytic" or "expanded"
    label: str


#: The runs, in table order.
RUNS: tuple[Run, ...] = (
    Run("white", "train-engine-white", "white", "first", "uniform white illumination"),
    Run("spectral", "train-engine", "spectral", "first", "+ spectral multiplexing"),
    Run("polar", "train-engine", "polar", "first", "+ polarization (unpol, LP)"),
    Run("full", "train-engine", "full", "first", "+ circular polarization (ours)"),
    Run("analytic", "train-engine", "full", "analytic", "full inputs, analytic materials only"),
    Run("expanded", "train-engine", "full", "expanded", "full inputs, expanded pBRDF tables only"),
)
_RUN = {r.name: r for r in RUNS}
#: Model fields every run replaces in the ``small`` preset: 128 px input, 8 x 8 tokens (CPU budget).
DEFAULT_OVERRIDES = {"image_size": 128, "canonical_size": 64, "train_pixels": 1024, "infer_chunk": 4096}
#: The test split every run is scored on, and its white twin.
TEST_SPLIT = "test-scenes"
WHITE_TEST_SPLIT = "test-scenes-white"


@dataclass(frozen=True)
class AblationConfig:
    """Settings of ``headless/ablation.py`` (every run shares them).

    Attributes:
        splits: folder holding the rendered splits (``out/splits``).
        out: output folder: one sub-folder per run, ``ablation.md`` and ``ablation.json``.
        scenes: training scenes per run.
        steps, batch_size, lr, seed: the training budget.
        overrides: :class:`network.config.ModelConfig` fields replaced in the ``config`` preset.
        runs: which runs (default all, in :data:`RUNS` order).
        limit: score only the first ``limit`` test scenes (None: all).
        jobs: evaluation worker processes.
        device: training device (``"cpu"``, ``"cuda"`` or ``"auto"``); CPU by default so that a
            table made on one machine can be reproduced on another.
    """

    splits: Path
    out: Path
    scenes: int = 500
    steps: int = 500
    batch_size: int = 4
    lr: float = 2e-4
    seed: int = 0
    config: str = "small"
    overrides: dict = field(default_factory=lambda: dict(DEFAULT_OVERRIDES))
    runs: tuple[str, ...] = tuple(r.name for r in RUNS)
    limit: int | None = None
    jobs: int = 1
    device: str = "cpu"

    def __post_init__(self) -> None:
        unknown = [r for r in self.runs if r not in _RUN]
        if unknown or not self.runs:
            raise ValueError(f"unknown ablation runs {unknown}; choose from {[r.name for r in RUNS]}")
        if self.scenes < 1 or self.steps < 1 or self.batch_size < 1:
            raise ValueError("scenes, steps and batch_size must be >= 1")


def scene_kind(meta: Mapping[str, Any]) -> str:
    """``"analytic"``, ``"expanded"`` or ``"mixed"``: the materials of a sample's objects.

    Example:
        >>> meta = {"materials": {"a": {"kind": "measured"}, "b": {"kind": "pplastic"}},
        ...         "objects": [{"material": "a"}]}
        >>> scene_kind(meta)
        'expanded'
    """
    measured = {meta["materials"][o["material"]]["kind"] == "measured" for o in meta["objects"]}
    return "expanded" if measured == {True} else "analytic" if measured == {False} else "mixed"


def run_indices(root: str | Path, run: str, count: int) -> list[int]:
    """The training sample indices of one run: ``count`` of the completed samples of ``root``.

    Raises:
        ValueError: fewer than ``count`` suitable samples (the message says how many there are).
    """
    spec = _RUN[run]
    done = sorted(pdataset.completed_indices(root, verify_hash=False))
    if spec.scenes == "first":
        chosen = done[:count]
    else:
        chosen = []
        for i in done:
            meta = json.loads(psample.sample_paths(root, i).sidecar.read_text(encoding="utf-8"))
            if scene_kind(meta) == spec.scenes:
                chosen.append(i)
                if len(chosen) == count:
                    break
    if len(chosen) < count:
        raise ValueError(f"{root}: run {run!r} needs {count} {spec.scenes} scenes, found {len(chosen)}")
    return chosen


def train_runs(cfg: AblationConfig, *, progress: bool = True, log: Callable[[str], None] = print) -> None:
    """Train every run of ``cfg`` (resuming; finished runs are left as they are)."""
    from .train import TrainConfig, train  # noqa: PLC0415

    for name in cfg.runs:
        spec = _RUN[name]
        data = Path(cfg.splits) / spec.data
        out = Path(cfg.out) / name
        indices = run_indices(data, name, cfg.scenes)
        log(f"ablation: training {name} ({spec.label}) on {len(indices)} scenes of {data}")
        train(
            TrainConfig(
                data=data, indices=tuple(indices), out=out, config=cfg.config, overrides=dict(cfg.overrides),
                steps=cfg.steps, batch_size=cfg.batch_size, lr=cfg.lr, seed=cfg.seed, inputs=spec.inputs,
                checkpoint_every=max(1, min(50, cfg.steps)), resume=True, tensorboard=False, device=cfg.device,
            ),
            progress=progress,
        )  # fmt: skip


def evaluate_runs(cfg: AblationConfig, stats: Mapping[str, Any], *, progress: bool = True) -> dict[str, Any]:
    """Score every trained run on its test split; returns the JSON-ready results."""
    from pbrdf.data.splits import require_role  # noqa: PLC0415

    from .checkpoint import load_checkpoint  # noqa: PLC0415
    from .evaluation import evaluate_dataset  # noqa: PLC0415

    results: dict[str, Any] = {}
    for name in cfg.runs:
        path = Path(cfg.out) / name / "model.pt"
        model, ckpt = load_checkpoint(path)
        split = WHITE_TEST_SPLIT if _RUN[name].inputs == "white" else TEST_SPLIT
        root = Path(cfg.splits) / split
        require_role(root, ("test",), "the ablation's scores")
        r = evaluate_dataset(
            model, ckpt, root, stats, limit=cfg.limit, lpips=False, progress=progress,
            jobs=cfg.jobs, checkpoint_path=path,
        )  # fmt: skip
        results[name] = {"split": split, "step": int(ckpt.get("step", 0)), **r}
    return results


def _cell(s: Mapping[str, Any] | None, digits: int) -> str:
    if not s or s.get("mean") is None:
        return "n/a"
    lo, hi = s["ci"]
    return f"{s['mean']:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


_COLUMNS = (
    ("normal_mae", "Normal MAE (deg)", 1),
    ("albedo_psnr", "Albedo PSNR (dB)", 2),
    ("albedo_si_psnr", "Albedo si-PSNR (dB)", 2),
    ("roughness_rmse", "Roughness RMSE", 3),
    ("metallic_rmse", "Metallic RMSE", 3),
)


def trend_lines(results: Mapping[str, Any]) -> list[str]:
    """The paper's two trends checked on the results (one line each; says when a run is missing).

    Each step's gain comes with its paired 95 % interval over scenes (:func:`paired_gain`) when the
    results have per-scene rows, and the line says whether the largest gain is separated from the
    next one by more than that noise.

    Example:
        >>> def r(n, m):
        ...     return {"methods": {"ours": {"normal_mae": {"mean": n}, "metallic_rmse": {"mean": m}}}}
        >>> res = {"white": r(30, .3), "spectral": r(20, .28), "polar": r(19, .25), "full": r(18, .2)}
        >>> trend_lines(res)[1]  # doctest: +NORMALIZE_WHITESPACE
        'holds: circular polarization lowers metallic RMSE most (spectral multiplexing +0.020, polarization +0.030,
        circular polarization +0.050; a positive value lowers the error)'
    """
    steps = (("white", "spectral", "spectral multiplexing"), ("spectral", "polar", "polarization"),
             ("polar", "full", "circular polarization"))  # fmt: skip
    out = []
    for key, unit, paper in (
        ("normal_mae", "deg", "spectral multiplexing"),
        ("metallic_rmse", "", "circular polarization"),
    ):
        gains: dict[str, tuple[float, tuple[float, float] | None]] = {}
        for a, b, what in steps:
            g = paired_gain(results, a, b, key)
            if g is not None:
                gains[what] = g
        metric = "normal MAE" if key == "normal_mae" else "metallic RMSE"
        if len(gains) < 3:
            out.append(f"not checked: {paper} lowers {metric} most (needs the white, spectral, polar and full runs)")
            continue
        nd = 2 if unit else 3
        suffix = " " + unit if unit else ""

        def fmt(g: float, ci: tuple[float, float] | None, nd: int = nd, suffix: str = suffix) -> str:
            band = f" [{ci[0]:+.{nd}f}, {ci[1]:+.{nd}f}]" if ci is not None else ""
            return f"{g:+.{nd}f}{suffix}{band}"

        best = max(gains, key=lambda w: gains[w][0])
        detail = ", ".join(f"{w} {fmt(*g)}" for w, g in gains.items())
        verdict = "holds" if best == paper else "does not hold"
        note = "a positive value lowers the error"
        if all(ci is not None for _, ci in gains.values()):
            note += "; paired 95 % intervals over scenes"
            lo = gains[best][1][0]  # type: ignore[index]
            if lo <= 0:
                note += f"; {best}'s interval includes 0, so the ranking is within noise"
        out.append(f"{verdict}: {paper} lowers {metric} most ({detail}; {note})")
    return out


def ablation_markdown(results: Mapping[str, Any], cfg: AblationConfig, command: str) -> str:
    """The table (one row per run, then the constant and baseline rows of the RGB test split)."""
    head = "| run | what the network sees / learns from | test split | " + " | ".join(h for _, h, _ in _COLUMNS) + " |"
    lines = [
        "# Table 3 at this machine's scale: input variants and pBRDF sources",
        "",
        f"Command: `{command}`",
        "",
        f"Every run: `{cfg.config}` with {json.dumps(cfg.overrides)}, {cfg.steps} steps x batch {cfg.batch_size}, "
        f"lr {cfg.lr:g}, seed {cfg.seed}, {cfg.scenes} training scenes. Scored through the real-capture path "
        "(raw brackets, decode, automatic mask) on the object coverage; per-scene means with 95 % bootstrap "
        "intervals over scenes.",
        "",
        head,
        "|" + "---|" * (3 + len(_COLUMNS)),
    ]
    for name in cfg.runs:
        if name not in results:
            continue
        r = results[name]
        cells = [_cell(r["methods"]["ours"].get(k), d) for k, _, d in _COLUMNS]
        lines.append(f"| {name} | {_RUN[name].label} | {r['split']} ({r['scenes']}) | " + " | ".join(cells) + " |")
    ref = next((results[n] for n in cfg.runs if n in results and results[n]["split"] == TEST_SPLIT), None)
    if ref is not None:
        for method, label in (("constant", "constant (normal to camera, train means)"),
                              ("baseline", "photometric stereo (calibrated)")):  # fmt: skip
            cells = [_cell(ref["methods"][method].get(k), d) for k, _, d in _COLUMNS]
            lines.append(f"| {method} | {label} | {ref['split']} ({ref['scenes']}) | " + " | ".join(cells) + " |")
    lines += ["", "Trends of the paper:", ""] + [f"- {t}" for t in trend_lines(results)]
    return "\n".join(lines) + "\n"


def run_ablation(
    cfg: AblationConfig,
    *,
    stats: Mapping[str, Any],
    command: str,
    train: bool = True,
    evaluate: bool = True,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> dict[str, Any] | None:
    """Train (resuming) and score every run; writes ``OUT/ablation.md`` and ``OUT/ablation.json``."""
    if train:
        train_runs(cfg, progress=progress, log=log)
    if not evaluate:
        return None
    results = evaluate_runs(cfg, stats, progress=progress)
    out = Path(cfg.out)
    atomic_write_text(out / "ablation.json", dumps_strict({"command": command, "results": results}) + "\n")
    atomic_write_text(out / "ablation.md", ablation_markdown(results, cfg, command))
    return results
