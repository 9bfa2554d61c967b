"""Spheres rendered from pBRDF tables, and the expansion's two figures with their captions.

Each material is drawn as a sphere seen along ``-z`` and lit by a distant light from
``(-0.3, 0.4, 1)`` (upper left, beside the camera), in three panels:

* colour: the intensity under unpolarized light at the renderer's R, G, B wavelengths
  (:data:`pbrdf.expansion.expand.RGB_WAVELENGTHS_NM`), divided by the sphere's own 99.5th
  percentile and shown with gamma 2.2, so a dark or a metallic sphere still shows its shading;
* DoLP under unpolarized light, on a colour scale from 0 to the sphere's own 99th percentile;
* the signed degree of circular polarization ``CP/S0 = s3/s0`` under light linearly polarized at
  45 degrees to the plane of the light and the camera, on a diverging scale symmetric about 0 and
  fitted to the sphere's own 99th percentile of ``|s3/s0|``. Under unpolarized light every table
  built from the seed set has DoCP exactly 0 (one reflection turns no unpolarized light
  circular), so that panel would say nothing; the display sends linear light, which a
  conductor's phase retardance turns partly circular, and which a dielectric leaves linear.

Every scalar panel has a colour bar and its range in its title; pixels off the sphere are grey.

Example:
    >>> print(seed_label(seeds.seed_table(seeds.SEED_MATERIALS[0], (4, 3, 4)), [0.88] * 3, 1.0, 0.0))
    spectralon: near-Lambertian diffuser
    albedo 0.97, IOR 1.35
    Disney fit: albedo (0.88, 0.88, 0.88), metallic 0.00
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pbrdf.brdf import seeds
from pbrdf.brdf.rusinkiewicz import reflection_frame_x
from pbrdf.brdf.table import PBRDFTable, evaluate
from pbrdf.expansion.expand import RGB_WAVELENGTHS_NM
from pbrdf.io.atomic import atomic_open
from pbrdf.polar.mueller import rotate_stokes_basis, stokes_basis

__all__ = ["sphere_polarimetry", "sphere_colour", "seed_label", "table_label", "material_figure", "caption"]

#: Direction towards the light, camera space (x right, y up, z toward the camera).
LIGHT = np.array([-0.3, 0.4, 1.0]) / np.linalg.norm([-0.3, 0.4, 1.0])
#: Seed roughness from which a dielectric seed is labelled a near-Lambertian diffuser (its
#: specular lobe is so wide that a Disney roughness fitted to it is undetermined).
LAMBERTIAN_ROUGHNESS = 0.9
#: Grey of the pixels off the sphere.
BACKGROUND = 0.82
_SEEDS = {m.name: m for m in seeds.SEED_MATERIALS}


def _sphere(size: int) -> tuple[np.ndarray, np.ndarray]:
    """``inside (size, size)`` bool and the camera-space normals ``(N, 3)`` of the pixels inside."""
    yy, xx = np.mgrid[0:size, 0:size]
    x = (xx + 0.5) / size * 2 - 1
    y = 1 - (yy + 0.5) / size * 2
    inside = x**2 + y**2 < 1
    n = np.stack([x, y, np.sqrt(np.clip(1 - x**2 - y**2, 0, 1))], -1)[inside]
    return inside, n


def sphere_polarimetry(table: PBRDFTable, size: int = 64, wavelength: float = 550.0) -> dict[str, np.ndarray]:
    """A sphere lit from beside the camera: intensity, DoLP, DoCP and the signed CP/S0 under 45-degree light.

    The view is along -z, the light comes from ``(-0.3, 0.4, 1)``. ``s0``, ``dolp`` and ``docp`` are
    under unpolarized light (degrees of polarization are frame-independent, so no frame rotation
    is needed for them); ``cp45`` is ``s3 / s0`` of the reflected light when the incident light is
    linearly polarized at 45 degrees to the plane of reflection (the plane of the light and the
    camera, the same for every pixel), which is frame-independent too. All are 0 off the sphere;
    ``inside`` marks the sphere.
    """
    inside, n = _sphere(size)
    view = np.array([0.0, 0.0, 1.0])
    # Local frame per pixel: z = n, x = any tangent.
    t = np.cross(n, [0.0, 1.0, 0.0])
    t /= np.maximum(np.linalg.norm(t, axis=-1, keepdims=True), 1e-9)
    b = np.cross(n, t)
    to_local = np.stack([t, b, n], axis=-2)
    wi = to_local @ view
    wo = to_local @ LIGHT
    m = evaluate(table, wi, wo, wavelength)
    s = m[..., 0]  # unpolarized input: first column
    # Linear light at 45 degrees to the plane of reflection, moved into Mitsuba's input basis.
    x = reflection_frame_x(wi, wo)
    r_in = rotate_stokes_basis(-wo, x, stokes_basis(-wo))
    s45 = np.einsum("nij,njk,k->ni", m, r_in, np.array([1.0, 0.0, 1.0, 0.0]))
    out = {k: np.zeros((size, size)) for k in ("s0", "dolp", "docp", "cp45")}
    lit = s[:, 0] > 1e-9
    out["s0"][inside] = s[:, 0]
    out["dolp"][inside] = np.hypot(s[:, 1], s[:, 2]) / np.maximum(s[:, 0], 1e-12) * lit
    out["docp"][inside] = np.abs(s[:, 3]) / np.maximum(s[:, 0], 1e-12) * lit
    out["cp45"][inside] = s45[:, 3] / np.maximum(s45[:, 0], 1e-12) * (s45[:, 0] > 1e-9)
    out["inside"] = inside
    return out


def sphere_colour(table: PBRDFTable, size: int = 64) -> np.ndarray:
    """Linear RGB intensity ``(size, size, 3)`` of the sphere under unpolarized light (0 off it)."""
    return np.stack([sphere_polarimetry(table, size, lam)["s0"] for lam in RGB_WAVELENGTHS_NM], axis=-1)


def _band(values: Sequence[float], nm: float) -> float:
    return float(values[seeds.WAVELENGTHS_NM.index(nm)])


def seed_label(table: PBRDFTable, albedo: Sequence[float], roughness: float, metallic: float) -> str:
    """Three lines: name and kind, the seed's own analytic parameters, its Disney fit.

    A near-Lambertian seed (a dielectric with seed roughness >= :data:`LAMBERTIAN_ROUGHNESS`) is
    called so, and its fitted Disney roughness is left out: without a lobe it is undetermined (a
    fit ends at a bound, 0 or 1). A table that is not a built-in seed (measured files) gets its
    name and the Disney fit.
    """
    a = ", ".join(f"{v:.2f}" for v in albedo)
    mat = _SEEDS.get(table.name or "")
    if mat is None:
        return f"{table.name}: measured\nDisney fit: albedo ({a}), roughness {roughness:.2f}, metallic {metallic:.2f}"
    name = mat.name.replace("_", " ")
    if mat.kind == "conductor":
        return (f"{name}: {mat.category} (conductor)\n"
                f"n {_band(mat.n, 550.0):.2f}, k {_band(mat.k, 550.0):.2f} at 550 nm, roughness {mat.roughness:.2f}\n"
                f"Disney fit: albedo ({a}), roughness {roughness:.2f}, metallic {metallic:.2f}")  # fmt: skip
    bands = "/".join(f"{_band(mat.albedo, nm):.2f}" for nm in (650.0, 550.0, 450.0))
    alb = f"{mat.albedo[0]:.2f}" if len(set(mat.albedo)) == 1 else f"{bands} (650/550/450 nm)"
    if mat.roughness >= LAMBERTIAN_ROUGHNESS:
        return (f"{name}: near-Lambertian diffuser\nalbedo {alb}, IOR {mat.ior:.2f}\n"
                f"Disney fit: albedo ({a}), metallic {metallic:.2f}")  # fmt: skip
    return (f"{name}: {mat.category} (dielectric)\nIOR {mat.ior:.2f}, roughness {mat.roughness:.2f}, albedo {alb}\n"
            f"Disney fit: albedo ({a}), roughness {roughness:.2f}, metallic {metallic:.2f}")  # fmt: skip


def table_label(name: str, albedo: Sequence[float], roughness: float, metallic: float) -> str:
    """Two lines for a generated table: its name and the Disney parameters it was generated for."""
    a = ", ".join(f"{v:.2f}" for v in albedo)
    return f"{name} (generated)\nDisney: albedo ({a}), roughness {roughness:.2f}, metallic {metallic:.2f}"


def _scale(values: np.ndarray, q: float, floor: float = 1e-4) -> tuple[float, bool]:
    """The ``q``-th percentile of ``values`` (at least ``floor``), and whether all of them are 0."""
    v = np.abs(values)
    zero = not bool(np.any(v > 1e-9))
    return max(float(np.percentile(v, q)) if v.size else 0.0, floor), zero


def _draw_material(sub, table: PBRDFTable, label: str, size: int) -> dict[str, object]:
    """The three panels of one material into subfigure ``sub``; returns its axes by panel name."""
    import matplotlib as mpl  # noqa: PLC0415

    pol = sphere_polarimetry(table, size)
    inside = pol["inside"]
    rgb = sphere_colour(table, size)
    white = max(float(np.percentile(rgb[inside].max(-1), 99.5)), 1e-12)
    rgb = np.where(inside[..., None], np.clip(rgb / white, 0, 1) ** (1 / 2.2), BACKGROUND)
    axes = sub.subplots(1, 3)
    axes[0].imshow(rgb, interpolation="nearest")
    axes[0].set_title("colour (gamma 2.2)", fontsize=7)
    dolp_max, dolp_zero = _scale(pol["dolp"][inside], 99.0)
    cp_max, cp_zero = _scale(pol["cp45"][inside], 99.0)
    panels = (
        ("dolp", "magma", 0.0, dolp_max, "DoLP = 0" if dolp_zero else f"DoLP, 0 to {dolp_max:.2g}"),
        ("cp45", "RdBu_r", -cp_max, cp_max, "CP/S0 = 0 (45° light)" if cp_zero else f"CP/S0 ±{cp_max:.2g} (45° light)"),
    )  # fmt: skip
    for ax, (key, cmap, lo, hi, title) in zip(axes[1:], panels, strict=True):
        cm = mpl.colormaps[cmap].with_extremes(bad=str(BACKGROUND))
        im = ax.imshow(np.where(inside, pol[key], np.nan), cmap=cm, vmin=lo, vmax=hi, interpolation="nearest")
        bar = sub.colorbar(im, ax=ax, fraction=0.046, pad=0.03)
        bar.ax.tick_params(labelsize=6)
        bar.formatter.set_powerlimits((-2, 2))
        bar.ax.yaxis.get_offset_text().set_fontsize(6)
        ax.set_title(title, fontsize=7)
    for ax in axes:
        ax.set_axis_off()
    sub.suptitle(label, fontsize=7, ha="left", x=0.02, multialignment="left")
    return dict(zip(("colour", "dolp", "cp45"), axes, strict=True))


def material_figure(
    path: str | Path,
    tables: Sequence[PBRDFTable],
    labels: Sequence[str],
    title: str,
    *,
    columns: int = 3,
    size: int = 64,
    dpi: int = 80,
) -> dict[tuple[int, str], tuple[int, int, int, int]]:
    """Write the spheres of ``tables`` (three panels each, ``columns`` materials per row) as a PNG.

    The PNG's ``Title`` text chunk holds ``title`` and its ``Description`` the labels (blank-line
    separated), so the figure names its materials in text too.

    Args:
        path: the PNG (written atomically).
        tables: the materials.
        labels: one (multi-line) label per material, drawn above its panels.
        title: the figure's title.
        columns: materials per row.
        size: sphere image size in pixels.
        dpi: resolution of the PNG.

    Returns:
        The pixel box ``(left, top, right, bottom)`` in the PNG of every panel, keyed by
        ``(material index, panel)`` with panel ``"colour"``, ``"dolp"`` or ``"cp45"``.
    """
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    n = len(tables)
    if n != len(labels) or n == 0:
        raise ValueError(f"need one label per table and at least one table; got {n} tables, {len(labels)} labels")
    cols = min(columns, n)
    rows = math.ceil(n / cols)
    fig = plt.figure(figsize=(4.9 * cols, 2.15 * rows + 0.4), dpi=dpi, layout="constrained")
    fig.suptitle(title, fontsize=9)
    subs = np.atleast_2d(fig.subfigures(rows, cols, wspace=0.02, hspace=0.03)).reshape(rows, cols)
    axes = {}
    for i, (t, label) in enumerate(zip(tables, labels, strict=True)):
        for key, ax in _draw_material(subs[i // cols, i % cols], t, label, size).items():
            axes[i, key] = ax
    try:
        with atomic_open(path) as f:
            fig.savefig(f, dpi=dpi, format="png", metadata={"Title": title, "Description": "\n\n".join(labels)})
        height = fig.canvas.get_width_height()[1]
        boxes = {}
        for key, ax in axes.items():
            e = ax.get_window_extent()
            boxes[key] = (math.ceil(e.x0), math.ceil(height - e.y1), math.floor(e.x1), math.floor(height - e.y0))
        return boxes
    finally:
        plt.close(fig)


def caption(name: str, count: int) -> str:
    """The report caption of ``figure_seeds.png`` or ``figure_generated.png`` showing ``count`` materials.

    Raises:
        KeyError: another file name.
    """
    how = (
        "Each material is a sphere lit from the upper left, beside the camera. Left: its colour under "
        "unpolarized light at the renderer's R, G, B wavelengths, each sphere divided by its own 99.5th "
        "percentile and shown with gamma 2.2 (compare shading and hue, not brightness). Middle: the degree of "
        "linear polarization under unpolarized light, colour bar from 0 to the sphere's own 99th percentile "
        "(given in the panel title). Right: the signed degree of circular polarization CP/S0 when the light is "
        "linearly polarized at 45° to the plane of the light and the camera, as the display's light is: red "
        "positive, blue negative, white 0, on a scale symmetric about 0 fitted to the sphere (±range in the "
        "title). Under unpolarized light the DoCP of every one of these materials is exactly 0: one reflection "
        "does not turn unpolarized light circular. Linear light becomes partly circular on a metal (phase "
        "retardance between s and p) and stays linear on a dielectric. Off the sphere: grey."
    )
    if name == "figure_seeds.png":
        return (
            f"All {count} seed materials of the expansion (built-in analytic stand-ins for the measured pBRDFs: "
            "spectralon, billiard resins, silicones, ceramics, plastics, metals). Each label gives the seed's own "
            "parameters (IOR and roughness of a dielectric, complex IOR n, k of a metal) and its Disney fit, the "
            "condition the generator learns from; a near-Lambertian seed has no fitted roughness (no lobe to fit). "
        ) + how
    if name == "figure_generated.png":
        return (
            f"{count} of the pBRDF tables generated from the seeds, each labelled with the Disney parameters it "
            "was drawn for (its ground truth in the rendered scenes). A small nonzero CP/S0 on a mostly dielectric "
            "table is the share of the conductor seeds in its PCA reconstruction. "
        ) + how
    raise KeyError(name)
