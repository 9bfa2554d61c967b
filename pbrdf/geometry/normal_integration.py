"""Depth from a normal map under a pinhole camera: discontinuity-aware least squares in log depth.

For a surface point ``P = d * r(u, v)`` on the ray ``r = ((u - cx) / fx, -(v - cy) / fy, -1)``
(:func:`pbrdf.sensor.projection.pixel_rays`, OpenGL camera axes) with unit normal ``n``, the
tangents ``dP/du`` and ``dP/dv`` are orthogonal to ``n``, which gives the gradient of the log
depth without any small-angle or orthographic approximation:

.. math::
    \\partial_u \\ln d = -\\frac{n_x}{f_x\\,(n\\cdot r)}, \\qquad
    \\partial_v \\ln d = \\frac{n_y}{f_y\\,(n\\cdot r)}

Every pair of 4-neighbours ``p, q`` inside the mask gives two one-sided equations,
``ln d_q - ln d_p = g(p)`` and ``= g(q)`` (each pixel's own gradient); the log depth solves the
weighted least-squares system. A depth jump at an occlusion makes the equations across it wrong,
and a residual test cannot find them (plain least squares spreads the error smoothly over both
surfaces). Instead every pixel splits its trust between its two sides along each axis, as in
bilateral normal integration (Cao et al., ECCV 2022): after each solve the side whose log-depth
step is larger gets the weight ``sigmoid((step_other^2 - step_this^2) / tau^2)``, so a pixel next
to a jump leans on its own surface and the surfaces on both sides keep their shapes. Log depth is
defined up to a constant (normals fix shape, not scale): the result is scaled so that the median
depth over the mask equals ``distance``.

Limits: a jump between two surfaces with the same normals is invisible to any normal integration;
disconnected parts of the mask get the same median log depth (the tiny ``anchor`` regulariser)
before the common scale; normals at grazing angles (``-n . r / |r|`` below ``min_cos``) are clipped
to ``min_cos`` so their gradients stay finite.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf.sensor.projection import pixel_rays

__all__ = ["integrate_normals", "log_depth_gradients"]


def log_depth_gradients(
    normal: ArrayLike, intrinsics: ArrayLike, *, min_cos: float = 0.05
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per-pixel ``(d ln d / du, d ln d / dv)`` of the surface with these normals.

    Args:
        normal: ``(H, W, 3)`` camera-frame unit normals (OpenGL axes, facing the camera).
        intrinsics: ``K (3, 3)`` of the normal map's pixel grid.
        min_cos: smallest cosine between a normal and the direction to the camera; below it the
            normal is tilted back toward the camera (grazing and back-facing normals stay finite).

    Returns:
        Two ``(H, W)`` arrays, per pixel column (u, right) and row (v, down).

    Example:
        >>> k = np.array([[100.0, 0, 2], [0, 100.0, 2], [0, 0, 1]])
        >>> gu, gv = log_depth_gradients(np.tile([0.0, 0.0, 1.0], (4, 4, 1)), k)
        >>> float(abs(gu).max()), float(abs(gv).max())  # facing the camera: constant depth
        (0.0, 0.0)
    """
    n = np.asarray(normal, dtype=np.float64)
    k = np.asarray(intrinsics, dtype=np.float64)
    h, w = n.shape[:2]
    r = pixel_rays(k, h, w)
    view = -r / np.linalg.norm(r, axis=-1, keepdims=True)  # unit direction to the camera
    cos = np.sum(n * view, axis=-1)
    # Tilt normals whose cosine is below min_cos toward the camera, in the plane of n and view.
    low = ~(cos >= min_cos)  # also NaN
    if low.any():
        tangent = n[low] - cos[low, None] * view[low]
        norm = np.linalg.norm(tangent, axis=-1, keepdims=True)
        tangent = np.where(norm > 1e-12, tangent / np.maximum(norm, 1e-300), 0.0)
        sin = np.sqrt(1.0 - min_cos**2)
        n = n.copy()
        n[low] = min_cos * view[low] + sin * tangent
        n[low & ~np.isfinite(n).all(-1)] = view[low & ~np.isfinite(n).all(-1)]
    ndotr = np.sum(n * r, axis=-1)  # < 0 for a normal facing the camera
    return -n[..., 0] / (k[0, 0] * ndotr), n[..., 1] / (k[1, 1] * ndotr)


def _edges(mask: NDArray[np.bool_]) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """``(p, q, axis)``: flat indices of 4-neighbour pairs inside the mask (q right of or below p)."""
    h, w = mask.shape
    idx = np.arange(h * w).reshape(h, w)
    right = mask[:, :-1] & mask[:, 1:]
    down = mask[:-1, :] & mask[1:, :]
    p = np.concatenate([idx[:, :-1][right], idx[:-1, :][down]])
    q = np.concatenate([idx[:, 1:][right], idx[1:, :][down]])
    axis = np.concatenate([np.zeros(int(right.sum()), np.int64), np.ones(int(down.sum()), np.int64)])
    return p, q, axis


# Systems of at most this many unknowns are solved directly (little fill-in on a grid this small).
_DIRECT = 20_000


class _Solver:
    """Solves the re-weighted normal equations (2-D grid Laplacians, symmetric positive definite).

    Direct factorisation fills in (31 s of CPU for 194k pixels, 10 solves) and plain conjugate
    gradients need thousands of steps. Algebraic multigrid (pyamg) preconditions conjugate
    gradients; the re-weighting changes the system a little per solve, and the previous solution
    is the start. The hierarchy is rebuilt when a solve needed more than ``rebuild`` steps (a
    re-weighting that cut the surface at its jumps leaves the first hierarchy a poor
    preconditioner: dozens of steps instead of about ten).
    """

    def __init__(self, rtol: float, rebuild: int = 30) -> None:
        self.pre, self.rtol, self.rebuild = None, rtol, rebuild

    def __call__(self, a, b: NDArray[np.float64], x0: NDArray[np.float64]) -> NDArray[np.float64]:
        import pyamg  # noqa: PLC0415
        from scipy.sparse.linalg import cg, spsolve  # noqa: PLC0415

        if a.shape[0] <= _DIRECT:  # small: a sparse direct solve beats building and running a hierarchy
            return spsolve(a.tocsc(), b)
        if self.pre is None:
            self.pre = pyamg.smoothed_aggregation_solver(a, symmetry="symmetric", max_coarse=500).aspreconditioner()
        steps = [0]

        def count(_x) -> None:
            steps[0] += 1

        x, _ = cg(a, b, x0=x0, rtol=self.rtol, atol=0.0, maxiter=500, M=self.pre, callback=count)
        if steps[0] > self.rebuild:
            self.pre = None
        return x


def integrate_normals(
    normal: ArrayLike,
    mask: ArrayLike,
    intrinsics: ArrayLike,
    distance: float,
    *,
    iterations: int = 10,
    tau: float = 0.002,
    min_cos: float = 0.05,
    anchor: float = 1e-6,
    rtol: float = 1e-6,
    settle: float = 1e-4,
) -> NDArray[np.float32]:
    """Depth (m along the viewing axis) of the surface whose normals are ``normal`` on ``mask``.

    Only the mask's bounding box is worked on. The re-weighting stops early once a solve moves no
    pixel's log depth by more than ``settle`` (a relative depth change: 1e-4 is 0.075 mm at 0.75 m).
    Each part of the mask that is not connected to the others gets mean log depth 0 before the
    common scale (what the ``anchor`` term alone gives when solved exactly).

    Args:
        normal: ``(H, W, 3)`` camera-frame unit normals (OpenGL axes, facing the camera).
        mask: ``(H, W)`` bool, the pixels to integrate.
        intrinsics: ``K (3, 3)`` of the normal map's pixel grid.
        distance: median depth of the result over the mask, in m (the capture distance or the
            rig's object distance).
        iterations: least-squares solves at most; 1 is plain (smooth across jumps), more re-weight
            the one-sided equations so that a pixel next to a depth jump trusts its other side.
        tau: scale of the squared log-depth steps compared on the two sides of a pixel (0.002:
            steps of a few tenths of a percent per pixel already choose a side).
        min_cos: see :func:`log_depth_gradients`.
        anchor: weight pulling each pixel's log depth toward 0 (keeps the systems definite).
        rtol: relative residual at which each conjugate-gradient solve stops.
        settle: stop re-weighting when a solve changed no log depth by more than this.

    Returns:
        ``(H, W)`` float32 depth, positive and finite on the mask, 0 elsewhere.

    Raises:
        ValueError: bad shapes, a non-positive distance or an empty mask.

    Example:
        >>> k = np.array([[100.0, 0, 4], [0, 100.0, 4], [0, 0, 1]])
        >>> d = integrate_normals(np.tile([0.0, 0.0, 1.0], (8, 8, 1)), np.ones((8, 8), bool), k, 0.7)
        >>> float(d.min()), float(d.max())
        (0.699999988079071, 0.699999988079071)
    """
    n = np.asarray(normal, dtype=np.float64)
    m = np.asarray(mask, dtype=bool)
    if n.ndim != 3 or n.shape[-1] != 3 or m.shape != n.shape[:2]:
        raise ValueError(f"expected normal (H, W, 3) and mask (H, W); got {n.shape} and {m.shape}")
    if not (np.isfinite(distance) and distance > 0):
        raise ValueError(f"distance must be positive and finite; got {distance!r}")
    if not m.any():
        raise ValueError("the mask is empty: nothing to integrate")
    rows, cols = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
    y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    k = np.array(intrinsics, dtype=np.float64)
    k[0, 2] -= x0  # the crop's own pixel grid
    k[1, 2] -= y0
    settings = _Settings(iterations, tau, min_cos, anchor, rtol, settle)
    z = _solve(n[y0:y1, x0:x1], m[y0:y1, x0:x1], k, settings)
    inside = m[y0:y1, x0:x1]
    z -= np.median(z[inside])
    depth = np.zeros(m.shape, np.float32)
    depth[y0:y1, x0:x1][inside] = distance * np.exp(np.clip(z[inside], -50.0, 50.0))
    return depth


@dataclass(frozen=True)
class _Settings:
    iterations: int
    tau: float
    min_cos: float
    anchor: float
    rtol: float
    settle: float


def _solve(n: NDArray[np.float64], m: NDArray[np.bool_], k: NDArray[np.float64], s: _Settings) -> NDArray[np.float64]:
    """``(H, W)`` log depth on ``m`` (0 elsewhere): the re-weighted least-squares solves."""
    from scipy import sparse  # noqa: PLC0415
    from scipy.ndimage import label  # noqa: PLC0415

    h, w = m.shape
    gu, gv = log_depth_gradients(np.where(m[..., None], n, [0.0, 0.0, 1.0]), k, min_cos=s.min_cos)
    cols = np.flatnonzero(m.ravel())
    where = np.full(h * w, -1, np.int64)
    where[cols] = np.arange(cols.size)
    p, q, axis = _edges(m)
    e = p.size
    out = np.zeros(h * w)
    if e == 0:  # isolated pixels: nothing relates their depths
        return out.reshape(h, w)
    grad = np.where(axis == 0, gu.ravel()[p], gv.ravel()[p]), np.where(axis == 0, gu.ravel()[q], gv.ravel()[q])
    ip, iq = where[p], where[q]
    d = sparse.csr_matrix((np.concatenate([-np.ones(e), np.ones(e)]), (np.tile(np.arange(e), 2),
                          np.concatenate([ip, iq]))), shape=(e, cols.size))  # fmt: skip
    # For every pixel and axis, the edge before it and the edge after it (-1: none).
    before = np.full((2, cols.size), -1, np.int64)
    after = np.full((2, cols.size), -1, np.int64)
    after[axis, ip] = np.arange(e)
    before[axis, iq] = np.arange(e)
    reg = s.anchor * sparse.identity(cols.size, format="csr")
    both = (after >= 0) & (before >= 0)
    # Each edge holds two one-sided equations, z_q - z_p = g(p) ("after p") and = g(q) ("before q");
    # a pixel splits its trust between its two sides by how much the depth jumps on each.
    w_after = np.where(after >= 0, np.where(before >= 0, 0.5, 1.0), 0.0)
    z = np.zeros(cols.size)
    solve = _Solver(s.rtol)
    for it in range(max(1, s.iterations)):
        wf = w_after[axis, ip]  # after p
        wb = np.where(before[axis, iq] >= 0, 1.0 - w_after[axis, iq], 0.0)  # before q
        wb = np.where(after[axis, iq] >= 0, wb, 1.0)
        weight = np.maximum(wf + wb, 1e-8)
        target = (wf * grad[0] + wb * grad[1]) / weight
        dw = d.T.multiply(weight)
        z, previous = solve((dw @ d + reg).tocsr(), dw @ target, z), z
        if it + 1 == s.iterations or (it > 0 and np.abs(z - previous).max() <= s.settle):
            break
        w_after = np.where(both, _side(d @ z, after, before, s.tau), w_after)
    # Parts of the mask with no edge between them: each at mean log depth 0 (the anchor's exact answer).
    parts, count = label(m)
    part = parts.ravel()[cols] - 1
    z -= (np.bincount(part, z, count) / np.bincount(part, minlength=count))[part]
    out[cols] = z
    return out.reshape(h, w)


def _side(step: NDArray, after: NDArray, before: NDArray, tau: float) -> NDArray:
    """The trust of each pixel in its "after" edge, from the squared log-depth steps on its two sides."""
    jump_after = np.where(after >= 0, step[np.maximum(after, 0)] ** 2, 0.0)
    jump_before = np.where(before >= 0, step[np.maximum(before, 0)] ** 2, 0.0)
    return 1.0 / (1.0 + np.exp(np.clip((jump_after - jump_before) / tau**2, -50.0, 50.0)))
