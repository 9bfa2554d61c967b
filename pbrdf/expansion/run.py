"""The expansion pipeline behind ``headless/expand_pbrdf.py``.

seed tables (built-in analytic set, or measured files) -> Disney fit of each -> streaming PCA
-> conditional VAE on (Disney parameters -> PCA weights) -> for each requested table: random
Disney parameters, sampled weights, reconstruction, validity filter (Givens-Kostinski +
Cloude, per-table acceptance, Cloude projection of the few invalid matrices), Disney re-fit,
Mitsuba tensor file + JSON sidecar. Every table is a function of ``(seed, index)``; a sidecar is
written last and atomically, so a killed run resumes where it stopped. Every file is written
atomically (:mod:`pbrdf.io.atomic`), and every run first removes the temporary files a killed
one left in the folders the expansion owns (``seeds/``, ``tables/``, ``model/``; in ``out`` itself
only those of the files written there).
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pbrdf.brdf import seeds
from pbrdf.brdf.table import PBRDFTable, load_table, resample, save_table, to_mitsuba_bands
from pbrdf.expansion import expand, figures
from pbrdf.expansion.figures import sphere_polarimetry
from pbrdf.io.atomic import atomic_open, atomic_write_text, remove_leftovers
from pbrdf.io.strict_json import dumps_strict

__all__ = ["ExpansionConfig", "ExpansionReport", "run_expansion", "load_measured", "sphere_polarimetry"]

log = logging.getLogger(__name__)


#: Files written into the output folder itself (its sub-folders belong to the expansion entirely).
OUT_FILES = ("materials.json", "manifest.json", "figure_generated.png", "figure_seeds.png")
#: Sub-folders of the output folder: seed cache, generated tables, PCA and generator.
OUT_DIRS = ("seeds", "tables", "model")


@dataclass(frozen=True)
class ExpansionConfig:
    """Flags of ``headless/expand_pbrdf.py``.

    Attributes:
        out: output folder.
        count: tables to generate, >= 1 (``--count``).
        seed: run seed.
        measured: folder of measured seed tables (``--input``); None: the built-in seed set.
        grid: table grid ``(phi_d, theta_d, theta_h)``, each >= 2.
        k_intensity, k_polarization: PCA components, >= 1 (``--components K_I K_P``); the PCA
            keeps at most one per seed table.
        generator_steps: generator training steps, >= 1.
        min_valid_fraction: per-table acceptance threshold of the validity filter, in [0, 1].
        max_attempts: candidates drawn per table before it counts as failed, >= 1.
        fit_samples: samples of each Disney fit, >= 5. A table whose fit fails the held-out check
            (``fit_ok`` False, :func:`pbrdf.expansion.expand.fit_table_disney`) is drawn again:
            its Disney label would be wrong ground truth.
        figures: generated tables shown in ``figure_generated.png``, >= 0 (0: no figures);
            ``figure_seeds.png`` shows every seed (:mod:`pbrdf.expansion.figures`).

    Raises:
        ValueError: a value out of its range; the message names the command-line flag.
    """

    out: Path
    count: int = 2000
    seed: int = 0
    measured: Path | None = None
    grid: tuple[int, int, int] = seeds.DEFAULT_GRID
    k_intensity: int = 10
    k_polarization: int = 10
    generator_steps: int = 1500
    min_valid_fraction: float = 0.95
    max_attempts: int = 4
    fit_samples: int = 600
    figures: int = 8

    def __post_init__(self) -> None:
        def whole(value: object) -> bool:
            return isinstance(value, int | np.integer) and not isinstance(value, bool)

        if (
            not (whole(self.k_intensity) and whole(self.k_polarization))
            or min(self.k_intensity, self.k_polarization) < 1
        ):
            raise ValueError(
                f"--components must be two integers >= 1 (K_I K_P), got {self.k_intensity} {self.k_polarization}"
            )
        for flag, value, low in (
            ("--count", self.count, 1),
            ("generator_steps", self.generator_steps, 1),
            ("max_attempts", self.max_attempts, 1),
            ("fit_samples", self.fit_samples, 5),
            ("figures", self.figures, 0),
        ):
            if not whole(value) or value < low:
                raise ValueError(f"{flag} must be an integer >= {low}, got {value!r}")
        if len(self.grid) != 3 or not all(whole(n) and n >= 2 for n in self.grid):
            raise ValueError(f"grid must be three integers >= 2, got {self.grid!r}")
        if not 0.0 <= self.min_valid_fraction <= 1.0:
            raise ValueError(f"min_valid_fraction must be in [0, 1], got {self.min_valid_fraction!r}")


@dataclass
class ExpansionReport:
    """What a run did, with timings and validity statistics."""

    written: int = 0
    skipped: int = 0
    failed: int = 0
    attempts: int = 0
    seconds: dict[str, float] = field(default_factory=dict)
    explained: dict[str, float] = field(default_factory=dict)

    def summary(self) -> str:
        """A few lines for the terminal."""
        acc = self.written / max(self.attempts, 1)
        lines = [
            f"tables written {self.written}, skipped {self.skipped} (already done), failed {self.failed}",
            f"acceptance rate {acc:.1%} over {self.attempts} generated candidates",
            "explained variance: " + ", ".join(f"{k} {v:.4f}" for k, v in self.explained.items()),
            "seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in self.seconds.items()),
        ]
        return "\n".join(lines)


def load_measured(folder: Path, grid: tuple[int, int, int]) -> list[PBRDFTable]:
    """Measured tables (``*.pbsdf``, ``*.hpbrdf``) resampled to the working grid and 5 bands."""
    files = sorted([*folder.glob("*.pbsdf"), *folder.glob("*.hpbrdf")])
    if not files:
        raise FileNotFoundError(f"--input {folder}: no .pbsdf or .hpbrdf files")
    out = []
    for f in files:
        t = to_mitsuba_bands(load_table(f))
        n_phi, n_td, n_th = grid
        t = resample(
            t,
            phi_d=np.linspace(-np.pi, np.pi, n_phi),
            theta_d=np.linspace(0, np.pi / 2, n_td),
            theta_h=np.linspace(0, np.pi / 2, n_th),
            wavelengths=np.asarray(seeds.WAVELENGTHS_NM),
        )
        m = np.nan_to_num(np.asarray(t.M))
        out.append(PBRDFTable(t.phi_d, t.theta_d, t.theta_h, t.wavelengths, m, name=f.stem))
    return out


def _source(tables: list[PBRDFTable]):
    """Chunk loader ``slice of bins -> (T, bins_c, W, 4, 4)`` over (possibly memory-mapped) tables.

    The PCA and the projection stream through it, so all tables are never in memory at once.
    """
    flat = [t.M.reshape(-1, *t.M.shape[3:]) for t in tables]

    def load(s: slice) -> np.ndarray:
        return np.stack([np.asarray(f[s], dtype=np.float64) for f in flat])

    return load, flat[0].shape[0]


def _random_condition(rng: np.random.Generator) -> np.ndarray:
    metallic = float(rng.random() < 0.3)
    albedo = rng.uniform(0.3, 1.0, 3) if metallic else rng.uniform(0.02, 0.95, 3)
    return np.array([*albedo, rng.uniform(0.25, 0.9), metallic])


def run_expansion(cfg: ExpansionConfig, *, progress: bool = True) -> ExpansionReport:
    """Run (or resume) an expansion into ``cfg.out``."""
    from pbrdf.expansion import generator  # noqa: PLC0415 - torch only here

    out = Path(cfg.out)
    tables_dir, model_dir = out / "tables", out / "model"
    removed = remove_leftovers(out, OUT_FILES) + [p for d in OUT_DIRS for p in remove_leftovers(out / d)]
    if removed:
        log.info("removed %d temporary file(s) of a killed run from %s", len(removed), out)
    tables_dir.mkdir(parents=True, exist_ok=True)
    model_dir.mkdir(parents=True, exist_ok=True)
    report = ExpansionReport()
    t0 = time.perf_counter()
    seed_set = load_measured(cfg.measured, cfg.grid) if cfg.measured else seeds.seed_tables(out / "seeds", cfg.grid)
    fits = [expand.fit_table_disney(t, n=cfg.fit_samples, seed=cfg.seed) for t in seed_set]
    conds = np.array([[*f.albedo, f.roughness, f.metallic] for f in fits])
    report.seconds["seeds_and_fits"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    pca_path, gen_path = model_dir / "pca.npz", model_dir / "generator.pt"
    source, n_bins = _source(seed_set)
    if pca_path.is_file():
        pca = expand.PCAModel.from_arrays(dict(np.load(pca_path)))
    else:
        pca = expand.fit_pca(
            source, n_bins=n_bins, k_intensity=cfg.k_intensity, k_polarization=cfg.k_polarization, grid_shape=cfg.grid
        )
        with atomic_open(pca_path) as f:
            np.savez(f, **pca.to_arrays())
    report.explained = {"intensity": float(pca.explained_i.sum()), "polarization": float(pca.explained_p.sum())}
    weights = expand.project(pca, source, n_bins=n_bins)
    if gen_path.is_file():
        model = generator.load_generator(gen_path)
    else:
        model, _ = generator.train_generator(weights, conds, steps=cfg.generator_steps, seed=cfg.seed)
        generator.save_generator(gen_path, model)
    report.seconds["pca_and_generator"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    grid_axes = (seed_set[0].phi_d, seed_set[0].theta_d, seed_set[0].theta_h, seed_set[0].wavelengths)
    shape = seed_set[0].M.shape
    bar = None
    if progress:
        from tqdm import tqdm  # noqa: PLC0415

        bar = tqdm(total=cfg.count, desc="expand pBRDFs", unit="table")
    for i in range(cfg.count):
        name = f"gen_{i:05d}"
        sidecar = tables_dir / f"{name}.json"
        if sidecar.is_file():
            report.skipped += 1
            if bar is not None:
                bar.update()
            continue
        done = False
        for attempt in range(cfg.max_attempts):
            rng = np.random.default_rng([cfg.seed, i, attempt])
            cond = _random_condition(rng)
            w = generator.sample_weights(model, cond[None], seed=int(rng.integers(2**31)))
            m = expand.reconstruct(pca, w.reshape(1, shape[3], -1))
            report.attempts += 1
            m, (verdict,) = expand.filter_tables(m, min_valid_fraction=cfg.min_valid_fraction)
            if not verdict.accepted:
                continue
            table = PBRDFTable(*grid_axes, m[0].reshape(shape).astype(np.float32), name=name)
            fit = expand.fit_table_disney(table, n=cfg.fit_samples, seed=cfg.seed)
            if not fit.fit_ok:  # its Disney label would be wrong ground truth: draw another table
                continue
            save_table(tables_dir / f"{name}.pbsdf", table, for_mitsuba=True)
            meta = {
                "name": name,
                "table": f"tables/{name}.pbsdf",
                "albedo": [float(v) for v in fit.albedo],
                "roughness": float(fit.roughness),
                "metallic": float(fit.metallic),
                "fit_rel_rmse": float(fit.rel_rmse),
                "fit_error": float(fit.fit_error),
                "fit_ok": bool(fit.fit_ok),
                "requested": {"albedo": cond[:3].tolist(), "roughness": float(cond[3]), "metallic": float(cond[4])},
                "validity": {"gk_fraction": verdict.gk_fraction, "cloude_fraction": verdict.cloude_fraction},
                "attempt": attempt,
                "seed": cfg.seed,
            }
            atomic_write_text(sidecar, dumps_strict(meta, indent=1))
            report.written += 1
            done = True
            break
        if not done:
            report.failed += 1
        if bar is not None:
            bar.set_postfix(failed=report.failed)
            bar.update()
    if bar is not None:
        bar.close()
    report.seconds["generate"] = time.perf_counter() - t0
    _write_index(out, cfg, report, fits, seed_set)
    return report


def _write_index(out: Path, cfg: ExpansionConfig, report: ExpansionReport, fits, seed_set) -> None:
    entries = [json.loads(p.read_text()) for p in sorted((out / "tables").glob("gen_*.json"))]
    materials = [{k: e[k] for k in ("name", "table", "albedo", "roughness", "metallic")} for e in entries]
    atomic_write_text(out / "materials.json", dumps_strict(materials, indent=1))
    manifest = {
        "format": "pdir-pbrdf-expansion/1",
        "count": len(entries),
        "requested": cfg.count,
        "seed": cfg.seed,
        "grid": list(cfg.grid),
        "wavelengths_nm": list(seeds.WAVELENGTHS_NM),
        "seed_source": str(cfg.measured) if cfg.measured else "built-in analytic seed set",
        "seeds": [
            {
                "name": t.name,
                "albedo": f.albedo.tolist(),
                "roughness": f.roughness,
                "metallic": f.metallic,
                "fit_rel_rmse": f.rel_rmse,
                "fit_error": f.fit_error,
                "fit_ok": f.fit_ok,
            }
            for t, f in zip(seed_set, fits, strict=True)
        ],  # fmt: skip
        "explained_variance": report.explained,
        "validity": {
            "mean_gk_fraction": float(np.mean([e["validity"]["gk_fraction"] for e in entries])) if entries else None,
            "mean_cloude_fraction": float(np.mean([e["validity"]["cloude_fraction"] for e in entries]))
            if entries
            else None,
            "acceptance_rate_this_run": report.written / max(report.attempts, 1),
        },
        "seconds": report.seconds,
    }
    atomic_write_text(out / "manifest.json", dumps_strict(manifest, indent=1))
    if cfg.figures and entries:
        pick = entries[:: max(1, len(entries) // cfg.figures)][: cfg.figures]
        figures.material_figure(
            out / "figure_generated.png",
            [load_table(out / e["table"]) for e in pick],
            [figures.table_label(e["name"], e["albedo"], e["roughness"], e["metallic"]) for e in pick],
            f"{len(pick)} of {len(entries)} generated pBRDF tables",
        )
        figures.material_figure(
            out / "figure_seeds.png",
            seed_set,
            [figures.seed_label(t, f.albedo, f.roughness, f.metallic) for t, f in zip(seed_set, fits, strict=True)],
            f"the {len(seed_set)} seed materials",
        )
