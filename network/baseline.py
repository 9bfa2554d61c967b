"""Classical baseline: calibrated colour photometric stereo under the display's three colour regions.

Each colour channel of the display lights the object from its own region (``rgb_halves``: red
the display's right half, green the left half, blue the upper half, as seen from the object), so
the three unpolarized (diffuse-dominant) maps ``unpol = s0 + s1`` are three images under three
extended lights. A Lambertian surface depolarizes the display's polarized light, so its ``unpol``
is the whole reflected radiance ``rho_c / pi * E_c``, ``E_c`` the irradiance from channel ``c``'s
lit region (radiance ``s0`` = :attr:`pbrdf.sensor.rig.DisplaySpec.radiance` times the pattern).

Model:
    The display is cut into planar patches of constant RGB radiance
    (:func:`pbrdf.sensor.patches.constant_patches`; one rectangle per colour combination for the
    built-in patterns). The irradiance of a surface
    point ``p`` with normal ``n`` from a uniform planar polygon has a closed form (Lambert's
    polygon formula, :func:`pbrdf.sensor.irradiance.polygon_irradiance_vectors`):

    .. math:: E_c(n) = n \\cdot \\Phi_c, \\qquad
              \\Phi_c = \\sum_q L_{qc} \\tfrac12 \\sum_i \\theta_{qi} \\gamma_{qi},

    with every patch first clipped to the part above the surface's horizon
    (:func:`irradiance_vectors` with ``normals``). While every patch is above the horizon,
    ``Phi_c`` (the irradiance vector of the region) does not depend on ``n`` and
    ``I_c = rho_c / pi * (n . Phi_c)`` is linear in ``n``.

Solve (:func:`predict`):
    1. Calibration (:func:`calibrate`): the patches in the camera frame and every pixel's lit
       point, first on the fronto-parallel plane through the object's centre.
    2. Albedo colour (:func:`albedo_chromaticity`): with one RGB image, per-channel albedo and
       normal are confounded (a grey-albedo assumption turns a coloured object's normals by tens
       of degrees, since the three regions all lie near the viewing axis and the 3x3 system is
       ill-conditioned). The baseline assumes one albedo per connected mask region (one material
       per object) and calibrates it from the image: with the right albedo ``k``,
       ``|Phi^-1 pi I / k| = 1`` at every pixel whose regions lie above its horizon.
    3. Normals (:func:`photometric_stereo`): Levenberg-Marquardt per pixel on the exact,
       horizon-clipped model ``I_c = k_c / pi * E_c(n)`` over unit normals facing the camera,
       from the linear solution. Three equations for two unknowns, so a channel whose region is
       partly or wholly below the horizon still constrains the normal.
    4. Depth (:func:`lit_point_depth`): the normals integrated to a depth map
       (:mod:`pbrdf.geometry.normal_integration`), its silhouette placed at the rim depth of a
       sphere of the region's apparent size around the object's centre; steps 1-3 are repeated
       at those points.

    With the LP maps given, a connected mask region whose light is mostly polarized (a metal: no
    diffuse signal for the Lambertian model) gets one constant normal, toward the camera.

Conventions: camera frame OpenGL (x right, y up, z toward the camera); normals in the camera
frame, facing the camera; world and display frames as in :mod:`pbrdf.sensor.rig`.

Not modelled: cast shadows and interreflections, specular reflection left in ``unpol``
(non-Lambertian materials), spatially varying albedo colour within a mask region.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf.sensor.irradiance import irradiance_vectors
from pbrdf.sensor.patches import constant_patches

__all__ = [
    "Calibration",
    "calibrate",
    "sample_geometry",
    "albedo_chromaticity",
    "photometric_stereo",
    "lit_point_depth",
    "predict",
    "predict_sample",
]

#: Smallest cosine between a normal and the view used when integrating depth (slopes up to about 10).
MIN_COS = 0.1


# --------------------------------------------------------------------------- calibration


@dataclass(frozen=True)
class Calibration:
    """What the per-pixel solve needs about the rig, in the camera frame.

    Attributes:
        vertices: ``(Q, 4, 3)`` display patch corners.
        radiance: ``(Q, 3)`` patch radiance per colour channel.
        points: ``(H, W, 3)`` the lit point of every pixel.
    """

    vertices: NDArray
    radiance: NDArray
    points: NDArray

    def phi(self, mask: ArrayLike) -> NDArray:
        """Unclipped irradiance vectors ``(P, 3, 3)`` at the mask's pixels."""
        return irradiance_vectors(self.vertices, self.radiance, self.points[np.asarray(mask, dtype=bool)])

    def condition_numbers(self, mask: ArrayLike) -> NDArray:
        """Condition number ``(P,)`` of the 3x3 system ``Phi`` at each of the mask's pixels."""
        return np.linalg.cond(self.phi(mask))


def calibrate(rig, intrinsics: ArrayLike, shape: tuple[int, int], depth: float | ArrayLike) -> Calibration:
    """Calibration of the display patches for an image of the rig's camera.

    Args:
        rig: :class:`pbrdf.sensor.rig.Rig` (display, camera pose).
        intrinsics: ``K (3, 3)`` of the image's pixel grid (e.g. a render's crop window).
        shape: ``(H, W)`` of the image.
        depth: distance of the lit points along the viewing axis (m, ``-z`` in the camera frame):
            a number (a fronto-parallel plane) or ``(H, W)``.
    """
    from pbrdf.sensor import projection  # noqa: PLC0415

    rays = projection.pixel_rays(intrinsics, shape[0], shape[1])
    points = rays * np.broadcast_to(np.asarray(depth, dtype=np.float64), tuple(shape))[..., None]
    patches = constant_patches(rig.display)
    verts = projection.transform_points(rig.camera.world_to_camera(), patches.vertices)
    return Calibration(vertices=verts, radiance=patches.radiance, points=points)


def sample_geometry(meta: Mapping, shape: tuple[int, int], mask: ArrayLike | None = None):
    """Rig, intrinsics and the centre-plane depth ``(H, W)`` of a dataset sample's sidecar.

    Each pixel gets the depth of the centre (``centre``, else the ``to_world`` translation) of the object whose
    centre projects nearest to the pixel's connected mask region (or to the pixel, without a
    mask).

    Returns:
        ``(rig, intrinsics (3, 3), depth (H, W))``.

    Raises:
        ValueError: the sidecar has no objects or no intrinsics.
    """
    from scipy import ndimage  # noqa: PLC0415

    from pbrdf.data.sample import sample_intrinsics  # noqa: PLC0415
    from pbrdf.sensor import projection  # noqa: PLC0415
    from pbrdf.sensor.rig import Rig  # noqa: PLC0415

    rig = Rig.from_dict(meta["rig"])
    objects = meta.get("objects") or []
    if not objects:
        raise ValueError("sample sidecar has no objects: cannot place the baseline's lit points")
    if "intrinsics" not in meta:
        raise ValueError("sample sidecar has no intrinsics: cannot cast the baseline's pixel rays")
    k = sample_intrinsics(meta, shape, "sample sidecar")
    # The bounding-box centre in the world (sidecars since 2026-11-24); older sidecars have only
    # the pose, whose translation is the centre for the centred built-in shapes.
    centres = np.array(
        [o["centre"] if "centre" in o else np.asarray(o["to_world"], dtype=np.float64)[:3, 3] for o in objects],
        dtype=np.float64,
    )
    cam = projection.transform_points(rig.camera.world_to_camera(), centres)
    depths = -cam[:, 2]
    if len(objects) == 1:
        return rig, k, np.full(shape, float(depths[0]))
    uv, _ = projection.camera_to_pixel(cam, k)
    vv, uu = np.mgrid[0 : shape[0], 0 : shape[1]] + 0.5
    d2 = (uu[..., None] - uv[:, 0]) ** 2 + (vv[..., None] - uv[:, 1]) ** 2
    depth = depths[np.argmin(np.nan_to_num(d2, nan=np.inf), axis=-1)]
    if mask is not None and np.any(mask):
        labels, count = ndimage.label(np.asarray(mask, dtype=bool))
        for lab in range(1, count + 1):
            sel = labels == lab
            c = np.array([uu[sel].mean(), vv[sel].mean()])
            depth[sel] = depths[np.argmin(np.nan_to_num(np.linalg.norm(uv - c, axis=-1), nan=np.inf))]
    return rig, k, depth


# --------------------------------------------------------------------------- per-pixel solve


def _patch_cosines(calib: Calibration, points: NDArray, normals: NDArray) -> NDArray:
    """``(P, Q, 4)`` cosine between each normal and the directions to the patch corners."""
    rel = calib.vertices[None] - points[:, None, None, :]
    return np.einsum("pqvk,pk->pqv", rel, normals) / np.linalg.norm(rel, axis=-1)


def _above_horizon(calib: Calibration, points: NDArray, normals: NDArray, margin: float = 0.0) -> NDArray:
    """``(P, 3)``: every lit patch of channel ``c`` lies above the horizon (cosine > ``margin``)."""
    if margin == 0.0:
        rel = calib.vertices[None] - points[:, None, None, :]
        ok_patch = np.einsum("pqvk,pk->pqv", rel, normals).min(axis=-1) > 0.0  # (P, Q)
    else:
        ok_patch = _patch_cosines(calib, points, normals).min(axis=-1) > margin
    lit = calib.radiance > 0  # (Q, 3)
    return np.all(ok_patch[:, :, None] | ~lit[None], axis=1)


def _model(calib: Calibration, points: NDArray, normals: NDArray, phi: NDArray) -> tuple[NDArray, NDArray]:
    """Exact irradiance ``E (P, 3)`` on surfaces ``normals`` at ``points`` and its gradient ``dE/dn (P, 3, 3)``.

    ``phi`` holds the points' unclipped irradiance vectors. The gradient of ``E_c(n)`` is the
    clipped irradiance vector (the horizon adds nothing, the integrand vanishes there), so
    ``E_c = n . dE_c/dn``.
    """
    grad = phi.copy()
    part = ~np.all(_above_horizon(calib, points, normals), axis=-1)
    if part.any():
        grad[part] = irradiance_vectors(calib.vertices, calib.radiance, points[part], normals[part])
    return np.einsum("pck,pk->pc", grad, normals), grad


def _det_inv3(a: NDArray) -> tuple[NDArray, NDArray]:
    """Determinants ``(P,)`` and inverses ``(P, 3, 3)`` (NaN where singular) of 3x3 matrices in closed form.

    The adjugate from cross products of the rows: columns ``r1 x r2, r2 x r0, r0 x r1`` over the
    determinant. Vectorised numpy, far faster than LAPACK's per-matrix calls for millions of
    3x3 systems.
    """
    r0, r1, r2 = a[..., 0, :], a[..., 1, :], a[..., 2, :]
    adj = np.stack([np.cross(r1, r2), np.cross(r2, r0), np.cross(r0, r1)], axis=-1)
    det = np.einsum("...i,...i->...", r0, adj[..., :, 0])
    ok = np.abs(det) > 1e-300
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(ok[..., None, None], adj / np.where(ok, det, 1.0)[..., None, None], np.nan)
    return det, inv


def _solve3(a: NDArray, b: NDArray) -> NDArray:
    """``a^-1 b`` per pixel, ``(P, 3)``; NaN where ``a`` is singular."""
    return np.einsum("pij,pj->pi", _det_inv3(a)[1], b)


def _chromaticity_linear(x: NDArray, inv: NDArray, max_cond: float = 1e4) -> NDArray | None:
    """Closed form of ``d = 1 / k`` from ``|Phi^-1 diag(d) x| = 1``: least squares in the products ``d_i d_j``.

    Returns None when the system is degenerate (condition number above ``max_cond`` after column
    scaling: the normals do not vary enough) or the products do not factor (a square <= 0).
    """
    m = np.einsum("pki,pkj->pij", inv, inv)
    pairs = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
    a = np.stack([(1 + (i != j)) * m[:, i, j] * x[:, i] * x[:, j] for i, j in pairs], axis=-1)
    col = np.maximum(np.linalg.norm(a, axis=0), 1e-300)
    if not np.all(np.isfinite(a)) or np.linalg.cond(a / col) > max_cond:
        return None
    p = np.linalg.lstsq(a / col, np.ones(len(a)), rcond=None)[0] / col
    if np.any(p[:3] <= 0):
        return None
    return np.sqrt(p[:3])


def albedo_chromaticity(unpol: ArrayLike, phi: NDArray, points: NDArray, calib: Calibration, *,
                        grey_prior: float = 3.0, iterations: int = 2) -> NDArray:  # fmt: skip
    """Per-channel albedo ``k (3,)`` of one material from its pixels' shading alone.

    With the right albedo, ``Phi^-1 pi I / k`` is a unit vector at every pixel whose colour
    regions lie above its horizon. First in closed form (linear least squares in the six
    products ``1 / (k_i k_j)`` over the pixels bright in every channel), then by robust least
    squares (soft L1) in ``log k`` over the pixels whose normal keeps every region above its
    horizon, re-selected ``iterations`` times. ``grey_prior`` weighs, per pixel, a prior toward a
    grey albedo, which decides alone when the normals hardly vary (a flat object, whose colour is
    not identifiable). Its default 3.0 was chosen on renders no evaluation reads (two tuning sets
    of 24 scenes, seeds 777 and 778, docs/measurements/baseline.md); 0.02 before.

    Args:
        unpol: ``(P, 3)`` unpolarized maps of the material's pixels.
        phi: ``(P, 3, 3)`` their unclipped irradiance vectors.
        points: ``(P, 3)`` their lit points.
        calib: the calibration (patches for the horizon test).
        grey_prior: weight of the grey prior per pixel.
        iterations: robust re-fits.
    """
    from scipy.optimize import least_squares  # noqa: PLC0415

    x = np.pi * np.asarray(unpol, dtype=np.float64)
    det, inv_all = _det_inv3(phi)
    good = np.all(x > 0, axis=-1) & (np.abs(det) > 1e-300)
    if good.sum() < 8:
        return np.full(3, 0.5)
    inv = np.where(good[:, None, None], inv_all, 0.0)
    bright = good & np.all(x > 0.3 * np.percentile(x[good], 95, axis=0), axis=-1)
    d = _chromaticity_linear(x[bright], inv[bright]) if bright.sum() >= 8 else None
    if d is None:  # grey, with the median length of the grey solution
        g = np.einsum("pck,pk->pc", inv[good], x[good])
        d = np.full(3, 1.0 / np.median(np.linalg.norm(g, axis=-1)))
    log_k = -np.log(d)
    view = -points / np.linalg.norm(points, axis=-1, keepdims=True)
    for _ in range(iterations):
        n = np.einsum("pck,pk->pc", inv, x / np.exp(log_k))
        n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
        sel = good & (np.sum(n * view, axis=-1) > 0.1)
        sel[sel] = np.all(_above_horizon(calib, points[sel], n[sel], margin=0.02), axis=-1)
        if sel.sum() < 8:
            break
        m_sel, x_sel, weight = inv[sel], x[sel], grey_prior * np.sqrt(sel.sum())

        def residual(lk, m_sel=m_sel, x_sel=x_sel, weight=weight):
            g = np.einsum("pck,pk->pc", m_sel, x_sel / np.exp(lk))
            return np.concatenate([np.linalg.norm(g, axis=-1) - 1.0, weight * (lk - lk.mean())])

        log_k = least_squares(residual, log_k, loss="soft_l1", f_scale=0.05).x
    return np.exp(log_k)


def _tangents(n: NDArray) -> tuple[NDArray, NDArray]:
    helper = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0.0, 1, 0]]))
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    return t1, np.cross(n, t1)


def _face_camera(n: NDArray, view: NDArray, min_cos: float = 0.02) -> NDArray:
    """Unit normals with ``n . view >= min_cos`` (tilted toward ``view`` where they are not)."""
    c = np.sum(n * view, axis=-1, keepdims=True)
    n = np.where(c < min_cos, n + (min_cos - c) * view, n)
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)


def _refine(calib: Calibration, points: NDArray, phi: NDArray, target: NDArray, n: NDArray,
            iterations: int) -> NDArray:  # fmt: skip
    """Levenberg-Marquardt per pixel on ``|E(n) - target|^2`` over unit normals facing the camera.

    Residuals are relative to ``|target|``; the Jacobian is exact (:func:`_model`); pixels leave
    the iteration once their step is below 1e-6 rad.
    """
    view = -points / np.linalg.norm(points, axis=-1, keepdims=True)
    norm = np.linalg.norm(target, axis=-1, keepdims=True)
    # A pixel with (almost) no diffuse signal carries no information: its residual is relative to
    # a floor at 1e-3 of the median signal, so it can neither overflow nor dominate.
    floor = 1e-3 * float(np.median(norm)) if norm.size else 0.0
    scale = np.maximum(norm, max(floor, 1e-30))
    n = _face_camera(n, view)
    e, grad = _model(calib, points, n, phi)
    r = (e - target) / scale
    cost = np.sum(r**2, axis=-1)
    mu = np.full(len(n), 1e-4)
    active = cost > 1e-16
    for _ in range(iterations):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        ni, vi, si = n[idx], view[idx], scale[idx]
        t1, t2 = _tangents(ni)
        jac = np.einsum("pck,pkj->pcj", grad[idx], np.stack([t1, t2], axis=-1)) / si[..., None]
        jtj = np.einsum("pci,pcj->pij", jac, jac)
        jtr = np.einsum("pci,pc->pi", jac, r[idx])
        damp = mu[idx, None, None] * (np.trace(jtj, axis1=1, axis2=2)[:, None, None] + 1e-300) * np.eye(2)
        m = jtj + damp  # 2x2 symmetric positive definite: solved in closed form
        det2 = m[:, 0, 0] * m[:, 1, 1] - m[:, 0, 1] * m[:, 1, 0]
        det2 = np.where(np.abs(det2) > 1e-300, det2, 1e-300)
        step = -np.stack([m[:, 1, 1] * jtr[:, 0] - m[:, 0, 1] * jtr[:, 1],
                          m[:, 0, 0] * jtr[:, 1] - m[:, 1, 0] * jtr[:, 0]], axis=-1) / det2[:, None]  # fmt: skip
        length = np.linalg.norm(step, axis=-1)
        step *= np.minimum(1.0, 0.5 / np.maximum(length, 1e-300))[:, None]  # at most about 30 degrees
        cand = _face_camera(ni + step[:, :1] * t1 + step[:, 1:] * t2, vi)
        ec, gc = _model(calib, points[idx], cand, phi[idx])
        rc = (ec - target[idx]) / si
        cc = np.sum(rc**2, axis=-1)
        better = cc < cost[idx]
        up = idx[better]
        n[up], r[up], cost[up], grad[up] = cand[better], rc[better], cc[better], gc[better]
        mu[idx] = np.where(better, mu[idx] * 0.2, mu[idx] * 10.0)
        active[idx] = (length > 1e-6) & (mu[idx] < 1e8) & (cost[idx] > 1e-16)
    return n


def photometric_stereo(unpol: ArrayLike, mask: ArrayLike, calib: Calibration, *, lp: ArrayLike | None = None,
                       albedo: Sequence[float] | None = None, iterations: int = 15, min_region_pixels: int = 64,
                       min_diffuse_fraction: float = 0.5) -> dict[str, NDArray]:  # fmt: skip
    """Calibrated colour photometric stereo at the calibration's points (steps 2-3 of the module docs).

    Args:
        unpol: ``(H, W, 3)`` unpolarized maps (R, G, B) in radiance units.
        mask: ``(H, W)`` pixels to solve.
        calib: :func:`calibrate` of the image.
        lp: ``(H, W, 3)`` the LP maps, or None. With them, a connected mask region whose median
            diffuse fraction ``unpol / (unpol + LP)`` (over the three channels) is below
            ``min_diffuse_fraction`` reflects mostly polarized (specular) light, e.g. a metal: the
            Lambertian model has nothing to fit there, and its normals are one constant, the
            direction from the region's mean point to the camera.
        albedo: the per-channel albedo when known; None calibrates it per connected mask region
            of at least ``min_region_pixels`` pixels (:func:`albedo_chromaticity`; smaller
            regions share the one of the whole mask).
        iterations: Levenberg-Marquardt iterations per pixel.
        min_region_pixels: smallest region calibrated on its own.
        min_diffuse_fraction: see ``lp``.

    Returns:
        ``normal (H, W, 3)`` unit, camera frame, facing the camera (0 outside the mask);
        ``albedo (H, W, 3)`` in [0, 1]: ``pi I_c / E_c(n)`` where channel ``c`` is lit, the
        calibrated albedo elsewhere; ``albedo_rgb (R, 3)`` the calibrated albedo per region.
    """
    from scipy import ndimage  # noqa: PLC0415

    img = np.asarray(unpol, dtype=np.float64)
    m = np.asarray(mask, dtype=bool) & np.all(np.isfinite(img), axis=-1)
    h, w = m.shape
    normal, alb = np.zeros((h, w, 3)), np.zeros((h, w, 3))
    if not m.any() or len(calib.vertices) == 0:
        return {"normal": normal.astype(np.float32), "albedo": alb.astype(np.float32), "albedo_rgb": np.zeros((0, 3))}
    points = calib.points[m]
    intensity = np.clip(img[m], 0.0, None)
    phi = irradiance_vectors(calib.vertices, calib.radiance, points)
    lab_img, count = ndimage.label(m)
    labels = lab_img[m] - 1
    specular = np.zeros(count, dtype=bool)
    if lp is not None:
        u = intensity.sum(-1)
        frac = u / np.maximum(u + np.asarray(lp, dtype=np.float64)[m].sum(-1), 1e-300)
        specular = np.array([np.median(frac[labels == lab]) < min_diffuse_fraction for lab in range(count)])
    diffuse = ~specular[labels]
    if albedo is not None:
        ks = np.tile(np.asarray(albedo, dtype=np.float64).reshape(3), (count, 1))
    else:
        whole = albedo_chromaticity(intensity[diffuse], phi[diffuse], points[diffuse], calib)
        ks = np.tile(whole, (count, 1))
        for lab in range(count if count > 1 else 0):
            sel = labels == lab
            if sel.sum() >= min_region_pixels and not specular[lab]:
                ks[lab] = albedo_chromaticity(intensity[sel], phi[sel], points[sel], calib)
    k = np.maximum(ks[labels], 1e-6)
    target = np.pi * intensity / k  # the irradiance E_c(n) each channel asks for
    view = -points / np.linalg.norm(points, axis=-1, keepdims=True)
    n = view.copy()
    lin = _solve3(phi[diffuse], target[diffuse])
    bad = ~np.all(np.isfinite(lin), axis=-1) | (np.linalg.norm(lin, axis=-1) < 1e-300)
    lin[bad] = view[diffuse][bad]
    lin /= np.linalg.norm(lin, axis=-1, keepdims=True)
    n[diffuse] = _refine(calib, points[diffuse], phi[diffuse], target[diffuse], lin, iterations)
    for lab in np.flatnonzero(specular):  # no diffuse signal: the direction from the region to the camera
        sel = labels == lab
        n[sel] = -points[sel].mean(0) / np.linalg.norm(points[sel].mean(0))
    irr = _model(calib, points, n, phi)[0]
    lit = irr > 0.05 * np.max(irr, axis=0, keepdims=True)
    normal[m] = n
    alb[m] = np.clip(np.where(lit, np.pi * intensity / np.maximum(irr, 1e-300), k), 0.0, 1.0)
    return {"normal": normal.astype(np.float32), "albedo": alb.astype(np.float32), "albedo_rgb": ks}


# --------------------------------------------------------------------------- depth


def lit_point_depth(normal: ArrayLike, mask: ArrayLike, intrinsics: ArrayLike, anchor: float | ArrayLike, *,
                    min_cos: float = MIN_COS, iterations: int = 1) -> NDArray:  # fmt: skip
    """Depth map ``(H, W)`` (m along the viewing axis) of the lit points of the surface with these normals.

    Each connected region of the mask is integrated on its own
    (:func:`pbrdf.geometry.normal_integration.integrate_normals`, which fixes shape, not scale) and
    scaled so that its outline's geometric-mean depth lies on the rim of a sphere centred at
    ``anchor`` with the region's apparent area (depth ``z - R^2 / z``, ``R`` the apparent radius
    in m): a convex object's silhouette lies near that rim. The result is kept within the
    region's largest apparent radius of the anchor.

    Args:
        normal: ``(H, W, 3)`` unit normals, camera frame.
        mask: ``(H, W)`` pixels with a surface.
        intrinsics: ``K (3, 3)``.
        anchor: depth of the object's centre, a number or ``(H, W)``.
        min_cos: smallest cosine between a normal and the direction to the camera used in the
            integration (0.1: slopes up to about 10, beyond which the silhouette's normals diverge).
        iterations: least-squares solves of the integration (1: plain least squares, as a smooth
            object needs; more re-weight across depth jumps).

    Returns:
        ``(H, W)``: the integrated depth on the mask, ``anchor`` elsewhere.
    """
    from scipy import ndimage  # noqa: PLC0415

    from pbrdf.geometry.normal_integration import integrate_normals  # noqa: PLC0415

    m = np.asarray(mask, dtype=bool)
    k = np.asarray(intrinsics, dtype=np.float64)
    anc = np.broadcast_to(np.asarray(anchor, dtype=np.float64), m.shape)
    out = np.array(anc, dtype=np.float64)
    labels, count = ndimage.label(m)
    outline = m & ~ndimage.binary_erosion(m)
    vv, uu = np.mgrid[0 : m.shape[0], 0 : m.shape[1]]
    for lab in range(1, count + 1):
        sel = labels == lab
        z = anc[sel]
        shape = integrate_normals(normal, sel, k, 1.0, iterations=iterations, min_cos=min_cos).astype(np.float64)
        # The silhouette of a sphere of the region's apparent area, per outline pixel.
        radius = np.sqrt(sel.sum() / np.pi) * np.median(z) / k[0, 0]
        edge = sel & outline
        rim = anc[edge] - min(radius**2 / np.median(z), 0.5 * radius)
        depth = shape[sel] * np.exp(np.mean(np.log(rim)) - np.mean(np.log(shape[edge])))
        u, v = uu[sel], vv[sel]
        reach = np.max(np.hypot(u - u.mean(), v - v.mean()) + 1.0) * np.median(z) / k[0, 0]
        out[sel] = np.clip(depth, np.maximum(z - reach, 1e-3), z + reach)
    return out


# --------------------------------------------------------------------------- entry points


def predict(unpol: ArrayLike, mask: ArrayLike, rig, intrinsics: ArrayLike, depth: float | ArrayLike, *,
            lp: ArrayLike | None = None, depth_passes: int = 1, albedo: Sequence[float] | None = None,
            iterations: int = 15) -> dict[str, NDArray]:  # fmt: skip
    """The whole baseline on one image (module docs, steps 1-4).

    Args:
        unpol: ``(H, W, 3)`` unpolarized maps (R, G, B).
        mask: ``(H, W)`` pixels to solve.
        rig: :class:`pbrdf.sensor.rig.Rig` of the capture.
        intrinsics: ``K (3, 3)`` of the image's pixel grid.
        depth: depth of the object's centre (m), a number or ``(H, W)`` (:func:`sample_geometry`).
        lp: ``(H, W, 3)`` LP maps for the specular-region test of :func:`photometric_stereo`, or None.
        depth_passes: integrate the normals to depth and solve again this many times (0: every
            point on the centre plane).
        albedo: known per-channel albedo, or None to calibrate it.
        iterations: Levenberg-Marquardt iterations per pixel.

    Returns:
        :func:`photometric_stereo`'s maps plus ``depth (H, W)``, the depth of the last pass's points.
    """
    unpol = np.asarray(unpol)
    shape = unpol.shape[:2]
    d = np.broadcast_to(np.asarray(depth, dtype=np.float64), shape)
    out = photometric_stereo(
        unpol, mask, calibrate(rig, intrinsics, shape, d), lp=lp, albedo=albedo, iterations=iterations
    )
    points_depth = d
    for _ in range(depth_passes):
        points_depth = lit_point_depth(out["normal"], mask, intrinsics, d)
        calib = calibrate(rig, intrinsics, shape, points_depth)
        out = photometric_stereo(unpol, mask, calib, lp=lp, albedo=albedo, iterations=iterations)
    out["depth"] = np.asarray(points_depth, dtype=np.float32)
    return out


def predict_sample(maps: ArrayLike, mask: ArrayLike, meta: Mapping, **kwargs) -> dict[str, NDArray]:
    """:func:`predict` on a dataset sample: its ``unpol`` (and ``LP``) maps, calibrated from its sidecar.

    Args:
        maps: ``(H, W, 9)`` nine maps (the first three are ``unpol`` R, G, B).
        mask: ``(H, W)`` pixels to solve.
        meta: the sample's sidecar (``rig``, ``intrinsics``, ``objects`` with ``to_world``).
        **kwargs: passed to :func:`predict`.
    """
    maps = np.asarray(maps)
    rig, k, depth = sample_geometry(meta, maps.shape[:2], mask)
    kwargs.setdefault("lp", maps[..., 3:6] if maps.shape[-1] >= 6 else None)
    return predict(maps[..., :3], mask, rig, k, depth, **kwargs)
