"""The built-in seed set: named analytic materials that stand in for the measured pBRDFs.

The 39 measured materials (KAIST pBRDF, hpBRDF) are gigabytes and cannot ship. These analytic
materials span the same categories (spectralon, billiard resins, silicones, ceramics,
plastics, gold, brass, chrome, steel, aluminium), with the dielectric pBRDF of Baek et al. (2018)
or the complex-IOR conductor (:mod:`pbrdf.brdf.microfacet`), tabulated on a small Rusinkiewicz grid on
demand and cached. ``expand_pbrdf.py --input DIR`` uses real tables instead; the pipeline
only sees :class:`pbrdf.brdf.table.PBRDFTable` either way.

Optical constants: dielectric IORs are typical published values for the material class
(resins and PMMA-like plastics about 1.49-1.55, silicone 1.41, alumina 1.76, PEEK 1.65, POM
1.48); metal n and k at 450/500/550/600/650 nm are rounded from standard tabulations (Johnson
and Christy 1972 for Au and Cu-Zn-like brass, Rakic 1998 for Al and Cr, iron for bearing
steel). Albedos and roughnesses are plausible choices, not measurements.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pbrdf.brdf import microfacet
from pbrdf.brdf.table import PBRDFTable, load_table, save_table, tabulate

__all__ = ["WAVELENGTHS_NM", "DEFAULT_GRID", "SeedMaterial", "SEED_MATERIALS", "seed_table", "seed_tables"]

#: Bands of the seed tables (the KAIST files' 450-650 nm).
WAVELENGTHS_NM = (450.0, 500.0, 550.0, 600.0, 650.0)
#: Default (phi_d, theta_d, theta_h) sizes: uniform grids like the measured ones, coarse enough
#: that 2000 expanded tables fit in about 2.5 GB. theta_h steps of 2.9 degrees resolve GGX lobes
#: down to roughness of about 0.25, the smallest the seed set uses.
DEFAULT_GRID = (12, 10, 32)


@dataclass(frozen=True)
class SeedMaterial:
    """One analytic seed material; per-band values are at :data:`WAVELENGTHS_NM`."""

    name: str
    category: str
    kind: str  # "dielectric" or "conductor"
    roughness: float
    albedo: tuple[float, ...] = (0.0,) * 5
    ior: float = 1.5
    n: tuple[float, ...] = ()
    k: tuple[float, ...] = ()


def _flat(v: float) -> tuple[float, ...]:
    return (v,) * 5


SEED_MATERIALS: tuple[SeedMaterial, ...] = (
    SeedMaterial("spectralon", "spectralon", "dielectric", 0.95, _flat(0.97), 1.35),
    SeedMaterial("white_billiard", "billiard resin", "dielectric", 0.25, _flat(0.85), 1.55),
    SeedMaterial("black_billiard", "billiard resin", "dielectric", 0.25, _flat(0.03), 1.55),
    SeedMaterial("red_billiard", "billiard resin", "dielectric", 0.28, (0.05, 0.04, 0.05, 0.45, 0.6), 1.55),
    SeedMaterial("blue_billiard", "billiard resin", "dielectric", 0.28, (0.45, 0.3, 0.08, 0.04, 0.04), 1.55),
    SeedMaterial("green_billiard", "billiard resin", "dielectric", 0.28, (0.06, 0.25, 0.35, 0.1, 0.05), 1.55),
    SeedMaterial("white_silicone", "silicone", "dielectric", 0.45, _flat(0.8), 1.41),
    SeedMaterial("pink_silicone", "silicone", "dielectric", 0.45, (0.55, 0.45, 0.45, 0.7, 0.75), 1.41),
    SeedMaterial("yellow_silicone", "silicone", "dielectric", 0.5, (0.1, 0.35, 0.7, 0.8, 0.82), 1.41),
    SeedMaterial("mint_silicone", "silicone", "dielectric", 0.5, (0.45, 0.65, 0.6, 0.45, 0.4), 1.41),
    SeedMaterial("ceramic_alumina", "ceramic", "dielectric", 0.35, _flat(0.82), 1.76),
    SeedMaterial("zirconia", "ceramic", "dielectric", 0.3, _flat(0.75), 2.15),
    SeedMaterial("peek", "plastic", "dielectric", 0.4, (0.35, 0.42, 0.5, 0.55, 0.58), 1.65),
    SeedMaterial("pom", "plastic", "dielectric", 0.3, _flat(0.78), 1.48),
    SeedMaterial(
        "gold", "metal", "conductor", 0.28, n=(1.46, 0.97, 0.43, 0.25, 0.17), k=(1.95, 1.87, 2.46, 2.98, 3.15)
    ),
    SeedMaterial("brass", "metal", "conductor", 0.3, n=(1.1, 0.9, 0.74, 0.53, 0.44), k=(2.1, 2.4, 2.6, 3.2, 3.7)),
    SeedMaterial("chrome", "metal", "conductor", 0.25, n=(2.3, 2.7, 2.9, 3.1, 3.2), k=(3.1, 3.2, 3.2, 3.3, 3.3)),
    SeedMaterial("bearing_steel", "metal", "conductor", 0.25, n=(2.4, 2.6, 2.8, 2.9, 3.0), k=(3.0, 3.1, 3.2, 3.3, 3.4)),
    SeedMaterial("aluminium", "metal", "conductor", 0.3, n=(0.62, 0.77, 0.96, 1.2, 1.5), k=(5.5, 6.0, 6.7, 7.3, 7.8)),
)


def _grid(sizes: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n_phi, n_td, n_th = sizes
    return (
        np.linspace(-np.pi, np.pi, n_phi),
        np.linspace(0.0, np.pi / 2, n_td),
        np.linspace(0.0, np.pi / 2, n_th),
    )


def seed_table(material: SeedMaterial, grid: tuple[int, int, int] = DEFAULT_GRID) -> PBRDFTable:
    """Tabulate one seed material (the analytic model, at the five bands)."""
    alpha = material.roughness**2

    def brdf(wi: np.ndarray, wo: np.ndarray, band: int) -> np.ndarray:
        if material.kind == "conductor":
            eta = complex(material.n[band], -material.k[band])
            return microfacet.conductor_pbrdf(wi, wo, eta=eta, alpha=alpha)
        return microfacet.dielectric_pbrdf(wi, wo, albedo=material.albedo[band], eta=material.ior, alpha=alpha)

    meta = {"category": material.category, "kind": material.kind, "roughness": material.roughness, "analytic": True}
    return tabulate(brdf, *_grid(grid), WAVELENGTHS_NM, name=material.name, metadata=meta)


def seed_tables(cache: str | Path | None = None, grid: tuple[int, int, int] = DEFAULT_GRID) -> list[PBRDFTable]:
    """All seed tables; with ``cache`` they are written there once and loaded afterwards."""
    out = []
    for mat in SEED_MATERIALS:
        path = None if cache is None else Path(cache) / f"{mat.name}_{grid[0]}x{grid[1]}x{grid[2]}.pbsdf"
        if path is not None and path.is_file():
            out.append(load_table(path, mmap=False))
            continue
        table = seed_table(mat, grid)
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            save_table(path, table)
        out.append(table)
    return out
