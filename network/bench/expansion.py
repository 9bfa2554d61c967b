"""Benchmark ``pbrdf``: PCA error against components, validity-filter throughput, expansion speed.

On the built-in seed tables (:func:`pbrdf.brdf.seeds.seed_tables`): the held-in reconstruction
error and time of the PCA (:mod:`pbrdf.expansion.expand`) for 2+2 to 15+15 components; the
vectorised Mueller validity filter (Givens-Kostinski and Cloude, :mod:`pbrdf.polar.validity`)
against a plain per-matrix numpy loop on a subset; and one whole expansion run
(:func:`pbrdf.expansion.run.run_expansion`) into a temporary folder, with its acceptance rate
and the time per valid table extrapolated to 2000 tables. Every timing follows
:mod:`network.bench.timing`.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from network.bench.timing import RULE, machine, time_call

__all__ = ["run"]

#: Matrices in the per-matrix loop (the vectorised filter runs on all of them).
LOOP_MATRICES = 2000


def _per_matrix_loop(mats: np.ndarray) -> None:
    """The validity tests one matrix at a time: eig of G M^T G M and eigvalsh of the coherency matrix."""
    from pbrdf.polar import validity  # noqa: PLC0415

    g = np.diag([1.0, -1.0, -1.0, -1.0])
    for m in mats:
        np.linalg.eig(g @ m.T @ g @ m)
        np.linalg.eigvalsh(validity.coherency_matrix(m))


def run(*, count: int = 40, repeat: int = 3, warmup: int = 1, seed: int = 0) -> dict:
    """Run the benchmark.

    Args:
        count: tables the timed expansion run generates.
        repeat: timed calls of the PCA and validity kernels (the expansion runs once).
        warmup: untimed calls before them.
        seed: seed of the expansion run.

    Returns:
        The JSON-ready result: ``reconstruction`` (per component count: timing keys,
        ``seconds``, ``rel_rmse_held_in``), ``validity_filter`` (throughputs and speed-up),
        ``expansion`` (tables written, acceptance rate, stage seconds, extrapolation),
        ``timing_rule`` and ``machine``.
    """
    from pbrdf.brdf import seeds  # noqa: PLC0415
    from pbrdf.expansion import expand  # noqa: PLC0415
    from pbrdf.expansion.run import ExpansionConfig, run_expansion  # noqa: PLC0415
    from pbrdf.polar import validity  # noqa: PLC0415

    result: dict = {"benchmark": "pbrdf", "grid": list(seeds.DEFAULT_GRID), "timing_rule": RULE}
    tabs = seeds.seed_tables()
    data = np.stack([np.asarray(t.M, dtype=np.float64).reshape(-1, 5, 4, 4) for t in tabs])
    norm = np.sqrt(np.mean(data**2))
    result["reconstruction"] = []
    for k in (2, 5, 10, 15):

        def fit_and_reconstruct(k=k):
            pca = expand.fit_pca(data, k_intensity=k, k_polarization=k)
            return expand.reconstruct(pca, expand.project(pca, data))

        timing, rec = time_call(
            fit_and_reconstruct,
            f"expand.fit_pca ({k}+{k} components) + project + reconstruct of {len(tabs)} seed tables",
            repeat=repeat,
            warmup=warmup,
        )
        result["reconstruction"].append({
            "components": f"{k}+{k}", **timing.to_dict(), "seconds": timing.median,
            "rel_rmse_held_in": float(np.sqrt(np.mean((rec - data) ** 2)) / norm),
        })  # fmt: skip
    mats = data.reshape(-1, 4, 4)
    mats = mats[mats[:, 0, 0] > 1e-8]
    vec, ok = time_call(
        lambda: validity.is_givens_kostinski(mats) & validity.is_cloude_physical(mats),
        f"validity.is_givens_kostinski & is_cloude_physical on {len(mats)} matrices at once",
        repeat=repeat,
        warmup=warmup,
    )
    sub = mats[:LOOP_MATRICES]
    loop, _ = time_call(
        lambda: _per_matrix_loop(sub),
        f"per-matrix numpy loop (eig of G M^T G M, eigvalsh of the coherency matrix) over {len(sub)} matrices",
        repeat=repeat,
        warmup=warmup,
    )
    per_matrix = loop.median / len(sub)
    result["validity_filter"] = {
        "matrices": int(len(mats)), "valid_fraction": float(ok.mean()),
        "vectorised": vec.to_dict(), "per_matrix_loop": loop.to_dict(),
        "matrices_per_second_vectorised": len(mats) / vec.median,
        "matrices_per_second_per_matrix_loop": 1.0 / per_matrix,
        "speedup": per_matrix * len(mats) / vec.median,
    }  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        cfg = ExpansionConfig(out=Path(tmp), count=count, seed=seed, figures=0)
        timing, report = time_call(
            lambda: run_expansion(cfg, progress=False),
            f"one pbrdf.expansion.run.run_expansion of {count} tables into an empty folder (one call: it writes files)",
            repeat=1,
            warmup=0,
        )
    per_table = report.seconds["generate"] / max(report.written, 1)
    result["expansion"] = {
        "tables_requested": count,
        "written": report.written,
        "acceptance_rate": report.written / max(report.attempts, 1),
        **timing.to_dict(),
        "seconds": timing.median,
        "stage_seconds": report.seconds,
        "seconds_per_valid_table": per_table,
        "extrapolated_minutes_for_2000": (
            per_table * 2000 + report.seconds["seeds_and_fits"] + report.seconds["pca_and_generator"]
        ) / 60,
    }  # fmt: skip
    result["machine"] = machine(numpy=np.__version__)
    return result
