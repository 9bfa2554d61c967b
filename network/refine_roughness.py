"""Test-time roughness per object from the LP lobe, trusted only where the capture can tell it.

Issue 27, item 3. The decoded LP map is the specular lobe (a dielectric's diffuse part
depolarizes), so its spread over an object's normals tells its roughness. Per object (a connected
component of the mask, dielectric pixels) the LP is re-rendered (:func:`network.rerender.rerender`)
with the network's normals at points of the integrated-depth surface, for every roughness of
:data:`ROUGHNESS_GRID`, and compared with the decoded LP up to a scale ``c`` per object:

.. math::
    L(r) = \\min_c \\Big[\\frac{\\sum_p w_p \\lVert o_p - c\\, m_p(r) \\rVert^2}{\\sum_p w_p \\lVert o_p \\rVert^2}
           + \\lambda (\\log c)^2\\Big]

(``o`` the decoded LP, ``m(r)`` the re-rendered one; ``lambda`` = :attr:`RoughnessParams.scale_prior`
ties the LP's level to the display radiance, 0 leaves it free). The answer is the MAP of
``T L(r) + (r - r_net)^2 / (2 sigma^2)`` with the network's mean roughness ``r_net`` as the prior
(:func:`map_roughness`), so a flat or noisy profile leaves the network's value.

The weights were chosen on the validation split ``val-next`` (docs/measurements/roughness.md).
The lobe is trusted only where the network's normals are (the specular lobe moves with a 15 deg
normal error by more than a roughness step): the weight ``w_p`` keeps pixels whose predicted normal
agrees with the normal of the integrated-depth surface (an integrable, self-consistent normal
field; :func:`normal_trust`), away from the mask's edges (occlusion boundaries, mixed pixels),
facing the camera, not dark, not saturated, and predicted dielectric. An object keeps the network's
roughness when it has too few trusted pixels, when its best fit explains too little of its LP
(relative residual above :attr:`RoughnessParams.max_residual`: metals taken for dielectrics, table
pBRDFs, shadows), or when the chosen roughness does not lower the fit loss below the network's own.
The chosen roughness replaces the object's mean, the network's texture within the object is kept
(a shift per object).

Cost: one integration of the normals and ``len(ROUGHNESS_GRID)`` re-renderings of at most
:data:`MAX_PIXELS` pixels under :data:`PATCHES` display patches (measured: docs/measurements/roughness.md).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from pbrdf.geometry.normal_integration import integrate_normals
from pbrdf.sensor import projection

from .rerender import display_patches, rerender

__all__ = [
    "MAX_PIXELS",
    "PATCHES",
    "ROUGHNESS_GRID",
    "RoughnessParams",
    "RoughnessResult",
    "lp_profiles",
    "map_roughness",
    "normal_trust",
    "object_profile",
    "refine_roughness",
]

#: Pixels re-rendered per capture (sampled evenly over the trusted pixels; 1024 chose the same roughness on val).
MAX_PIXELS = 512
#: Display patches per colour region (the lobe is widened to each patch's solid angle).
PATCHES = (8, 8)
#: Roughness values the LP is re-rendered at (the profile is interpolated between them, monotone cubic).
#: Seven values with a monotone cubic between them choose what the earlier 14 with linear interpolation did
#: (docs/measurements/roughness.md: per-object error against the truth on val 0.1235 against 0.1249).
ROUGHNESS_GRID = np.array([0.05, 0.15, 0.25, 0.4, 0.6, 0.8, 1.0])
#: Re-weighting solves of the normal integration behind the trust angle (the first few set the surface).
INTEGRATION_ITERATIONS = 3
_SCALES = np.exp(np.linspace(np.log(1 / 16), np.log(16), 49))  # LP level c searched per object


@dataclass(frozen=True)
class RoughnessParams:
    """Weights and thresholds of the estimate (chosen on the validation splits only).

    Attributes:
        max_angle_deg: a pixel's normal is trusted when it is within this angle of the integrated surface's.
        edge_px: pixels closer than this to the mask's edge are not trusted.
        min_pixels: fewest trusted pixels an object needs.
        temperature: ``T``, the weight of the fit loss against the prior.
        sigma: ``sigma``, the prior's width around the network's roughness.
        max_residual: objects whose best relative residual is above this keep the network's roughness.
        scale_prior: ``lambda`` on ``(log c)^2`` (0: the LP's level is free).
        broadening: the fit is read as ``r_fit - broadening`` (the network's normal errors widen the
            observed lobe against the re-rendered one, so the fit comes out rougher than the surface).
    """

    max_angle_deg: float = 15.0
    edge_px: float = 2.0
    min_pixels: int = 24
    temperature: float = 10.0
    sigma: float = 0.1
    max_residual: float = 0.7
    scale_prior: float = 0.0
    broadening: float = 0.05


@dataclass
class RoughnessResult:
    """What :func:`refine_roughness` did.

    Attributes:
        pred: the maps (the network's ``pred`` with the refined roughness, or the network's own).
        refined: whether any roughness was changed.
        objects: per object (component id) ``{"network", "fit", "chosen", "residual", "pixels", "kept"}``.
        seconds: wall time.
        message: one line for the user.
    """

    pred: dict[str, np.ndarray]
    refined: bool
    objects: dict[int, dict] = field(default_factory=dict)
    seconds: float = 0.0
    message: str = ""


def normal_trust(
    normal: np.ndarray, mask: np.ndarray, intrinsics: np.ndarray, distance_m: float, iterations: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Angle (deg) between each predicted normal and the normal of the surface integrated from them.

    Args:
        normal: ``(H, W, 3)`` camera-frame unit normals.
        mask: ``(H, W)`` bool.
        intrinsics: ``K (3, 3)``.
        distance_m: the object's distance (sets the integrated surface's scale).
        iterations: re-weighting solves (default :data:`INTEGRATION_ITERATIONS`).

    Returns:
        ``(angle, depth)``: ``(H, W)`` angles in degrees (180 off the mask and where the surface's
        normal is undefined) and the integrated depth (m along the viewing axis, 0 off the mask).

    Example:
        >>> k = np.array([[100.0, 0, 16], [0, 100.0, 16], [0, 0, 1]])
        >>> n = np.zeros((32, 32, 3)); n[..., 2] = 1.0
        >>> a, _ = normal_trust(n, np.ones((32, 32), bool), k, 0.7)
        >>> bool(np.median(a) < 1.0)
        True
    """
    h, w = mask.shape
    out = np.full((h, w), 180.0)
    if not mask.any():
        return out, np.zeros((h, w))
    its = INTEGRATION_ITERATIONS if iterations is None else iterations
    depth = integrate_normals(normal, mask, intrinsics, distance_m, iterations=its).astype(np.float64)
    pts = depth[..., None] * projection.pixel_rays(intrinsics, h, w)
    du, dv = np.gradient(pts, axis=1), np.gradient(pts, axis=0)
    n = np.cross(du, dv)
    # Orient towards the camera (the camera sits at the origin).
    n *= np.where(np.sum(n * pts, -1, keepdims=True) > 0, -1.0, 1.0)
    norm = np.linalg.norm(n, axis=-1) * np.linalg.norm(normal, axis=-1)
    cos = np.sum(n * normal, -1) / np.maximum(norm, 1e-12)
    ok = mask & (norm > 0) & np.isfinite(cos)
    out[ok] = np.degrees(np.arccos(np.clip(cos[ok], -1.0, 1.0)))
    return out, np.where(mask & np.isfinite(depth), depth, 0.0)


def lp_profiles(normal: np.ndarray, points: np.ndarray, rig, grid: np.ndarray | None = None) -> np.ndarray:
    """Re-rendered LP of a dielectric at every roughness of ``grid``.

    Args:
        normal: ``(P, 3)`` camera-frame normals.
        points: ``(P, 3)`` camera-frame points in m.
        rig: the capture's :class:`pbrdf.sensor.rig.Rig`.
        grid: ``(G,)`` roughness values (default :data:`ROUGHNESS_GRID`).

    Returns:
        ``(G, P, 3)`` LP in the display's radiance units.
    """
    grid = ROUGHNESS_GRID if grid is None else grid
    p = normal.shape[0]
    patches = display_patches(rig, PATCHES)
    n = torch.from_numpy(np.ascontiguousarray(normal.T, dtype=np.float32))[None]
    x = torch.from_numpy(np.ascontiguousarray(points.T, dtype=np.float32))[None]
    ones, zero = torch.ones(1, 3, p), torch.zeros(1, 1, p)
    out = []
    with torch.no_grad():
        for r in grid:
            lp = rerender(n, ones, torch.full((1, 1, p), float(r)), zero, x, patches, chunk=1024)["lp"]
            out.append(lp[0].T.double().numpy())
    return np.stack(out)


def object_profile(obs: np.ndarray, model: np.ndarray, weight: np.ndarray, scale_prior: float = 0.0) -> np.ndarray:
    """The fit loss ``L(r)`` per grid roughness (module docs), finite, in [0, 1 + prior].

    Args:
        obs: ``(P, 3)`` decoded LP.
        model: ``(G, P, 3)`` re-rendered LP per roughness.
        weight: ``(P,)`` pixel weights >= 0.
        scale_prior: ``lambda`` on ``(log c)^2``.

    Returns:
        ``(G,)`` relative residuals (1 where there is no signal).

    Example:
        >>> m = np.random.default_rng(0).random((3, 50, 3))
        >>> int(np.argmin(object_profile(2.0 * m[1], m, np.ones(50))))
        1
    """
    w = weight[:, None]
    energy = float(np.sum(w * obs * obs))
    if not energy > 1e-30:
        return np.ones(model.shape[0])
    om = np.sum(w * obs * model, axis=(1, 2))  # (G,)
    mm = np.sum(w * model * model, axis=(1, 2))
    c = _SCALES[None, :]
    loss = (energy - 2 * c * om[:, None] + c * c * mm[:, None]) / energy + scale_prior * np.log(c) ** 2
    return np.clip(np.nan_to_num(loss.min(axis=1), nan=1.0, posinf=1.0), 0.0, None)


def _interp(x: np.ndarray, grid: np.ndarray, profile: np.ndarray) -> np.ndarray:
    """Monotone cubic interpolation of ``profile`` on ``grid`` at ``x`` (clamped to the grid's ends)."""
    from scipy.interpolate import PchipInterpolator  # noqa: PLC0415

    return PchipInterpolator(grid, profile)(np.clip(x, grid[0], grid[-1]))


def map_roughness(
    profile: np.ndarray, r_net: float, params: RoughnessParams, grid: np.ndarray | None = None
) -> tuple[float, float, float]:
    """MAP roughness of ``T L(r + b) + (r - r_net)^2 / (2 sigma^2)`` on a 0.005 grid (``b`` the broadening).

    Args:
        profile: ``(G,)`` fit loss at ``grid``.
        r_net: the network's roughness (the prior's mean).
        params: :class:`RoughnessParams`.
        grid: ``(G,)`` the roughness values of ``profile`` (default :data:`ROUGHNESS_GRID`).

    Returns:
        ``(r_map, loss_at_map, loss_at_network)``.

    Example:
        >>> prof = (ROUGHNESS_GRID - 0.3) ** 2
        >>> r, _, _ = map_roughness(prof, 0.3, RoughnessParams(broadening=0.0))
        >>> round(r, 3)
        0.3
    """
    grid = ROUGHNESS_GRID if grid is None else grid
    fine = np.linspace(grid[0], grid[-1], 191)
    lf = _interp(fine + params.broadening, grid, profile)
    r0 = float(np.clip(r_net, fine[0], fine[-1]))
    energy = params.temperature * lf + (fine - r0) ** 2 / (2 * params.sigma**2)
    i = int(np.argmin(energy))
    return float(fine[i]), float(lf[i]), float(_interp(np.array(r0 + params.broadening), grid, profile))


def _pixel_weight(obs: np.ndarray, metallic: np.ndarray, view_cos: np.ndarray) -> np.ndarray:
    """``(P,)`` in {0, 1}: dielectric, facing the camera, neither dark nor saturated (``obs`` ``(P, 9)``)."""
    unpol = obs[:, :3].sum(1)
    top = max(float(np.percentile(unpol, 99)), 1e-12) if unpol.size else 1.0
    lit = unpol > 0.02 * top
    unsaturated = unpol < 0.98 * max(float(unpol.max()), 1e-12) if unpol.size else lit
    return ((metallic < 0.5) & lit & unsaturated & (view_cos > 0.3)).astype(np.float64)


def _samples(
    pred: dict[str, np.ndarray], maps: np.ndarray, intrinsics: np.ndarray, distance_m: float, params, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """At most :data:`MAX_PIXELS` trusted pixels: flat indices, normals, points on the integrated surface, maps."""
    from scipy import ndimage  # noqa: PLC0415

    mask = pred["mask"][..., 0] > 0
    h, w = mask.shape
    angle, depth = normal_trust(pred["normal"], mask, intrinsics, distance_m)
    inner = ndimage.distance_transform_edt(mask) > params.edge_px
    idx = np.flatnonzero(mask & inner & (angle < params.max_angle_deg))
    if idx.size > MAX_PIXELS:  # the rendering's cost: an even sample of the trusted pixels
        idx = np.sort(np.random.default_rng(seed).choice(idx, MAX_PIXELS, replace=False))
    z = depth.reshape(-1)[idx]
    points = projection.pixel_rays(intrinsics, h, w).reshape(-1, 3)[idx] * np.where(z > 0, z, distance_m)[:, None]
    normal = pred["normal"].reshape(-1, 3)[idx].astype(np.float64)
    norms = np.linalg.norm(points, axis=1) * np.linalg.norm(normal, axis=1)
    view_cos = -np.sum(normal * points, 1) / np.maximum(norms, 1e-12)
    obs = np.nan_to_num(maps.reshape(h * w, -1)[idx].astype(np.float64))
    keep = np.flatnonzero(_pixel_weight(obs, pred["metallic"].reshape(-1)[idx], view_cos) > 0)  # only these rendered
    return idx[keep], normal[keep], points[keep], obs[keep]


def refine_roughness(
    pred: dict[str, np.ndarray],
    maps: np.ndarray,
    intrinsics: np.ndarray,
    rig,
    distance_m: float,
    *,
    params: RoughnessParams | None = None,
    seed: int = 0,
    skip: dict[int, str] | None = None,
) -> RoughnessResult:
    """Per-object roughness from the decoded LP with the network's as the prior (module docs).

    Args:
        pred: :func:`network.infer.predict`'s maps ``(H, W, C)`` with ``mask``.
        maps: ``(H, W, 9)`` the decoded maps in the display's radiance units (calibrated).
        intrinsics: ``K (3, 3)`` of the maps' grid.
        rig: the capture's :class:`pbrdf.sensor.rig.Rig`.
        distance_m: the object's distance in m.
        params: weights and thresholds (default :class:`RoughnessParams`).
        seed: pixel sampling seed.
        skip: components (ids of ``scipy.ndimage.label`` of the mask) that keep the network's roughness, with
            the reason (the guard's, :func:`network.refine.guard_objects`).

    Returns:
        :class:`RoughnessResult`; its roughness is finite and in [0, 1].
    """
    from scipy import ndimage  # noqa: PLC0415

    params = params or RoughnessParams()
    start = time.perf_counter()
    mask = pred["mask"][..., 0] > 0
    if not mask.any():
        return RoughnessResult(pred, False, {}, time.perf_counter() - start, "roughness kept: the mask is empty")
    labels, _ = ndimage.label(mask)
    idx, normal, points, obs = _samples(pred, maps, intrinsics, distance_m, params, seed)
    model = lp_profiles(normal, points, rig) if idx.size else np.zeros((len(ROUGHNESS_GRID), 0, 3))
    h, w = mask.shape
    rough = pred["roughness"][..., 0].astype(np.float64)
    lab = labels.reshape(-1)[idx]
    out_rough, objects = rough.copy(), {}
    for k in range(1, int(labels.max()) + 1):
        sel = lab == k
        obj = {"network": float(rough[labels == k].mean()), "pixels": int(sel.sum()), "kept": True}
        objects[k] = obj
        if sel.sum() < params.min_pixels:
            obj["why"] = "too few trusted pixels"
            continue
        if skip and skip.get(k):
            obj["why"] = skip[k]
            continue
        profile = object_profile(obs[sel, 3:6], model[:, sel], np.ones(int(sel.sum())), params.scale_prior)
        chosen, loss_chosen, loss_net = map_roughness(profile, float(rough[idx[sel] // w, idx[sel] % w].mean()), params)
        obj.update(fit=float(ROUGHNESS_GRID[np.argmin(profile)]), chosen=chosen, residual=float(profile.min()))
        if profile.min() > params.max_residual:
            obj["why"] = "the LP lobe explains too little of the decoded LP"
        elif not loss_chosen < loss_net * (1.0 - 1e-3):  # a float-level gain is no gain
            obj["why"] = "no lower fit loss than the network's roughness"
        else:
            obj["kept"] = False
            dielectric = (labels == k) & (pred["metallic"][..., 0] < 0.5)
            out_rough[dielectric] += chosen - obj["network"]
    changed = [k for k, o in objects.items() if not o["kept"]]
    seconds = time.perf_counter() - start
    if not changed:
        return RoughnessResult(pred, False, objects, seconds, "roughness kept: no object's LP fit was trusted")
    new = np.where(mask, np.clip(out_rough, 0.0, 1.0), 0.0)[..., None].astype(np.float32)
    shown = ", ".join(f"{objects[k]['network']:.2f}->{objects[k]['chosen']:.2f}" for k in changed)
    return RoughnessResult({**pred, "roughness": new}, True, objects, seconds,
                           f"refined the roughness of {len(changed)} object(s) ({shown})")  # fmt: skip
