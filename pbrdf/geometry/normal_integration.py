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

__all__ = ["auto_cell", "integrate_normals", "log_depth_gradients"]


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
    gradients need thousands of steps, so conjugate gradients are preconditioned, and the previous
    solution is the start. Two preconditioners: algebraic multigrid (pyamg smoothed aggregation,
    ``cell`` None), or a two-grid cycle (``cell``: each unknown's cell of :class:`_TwoGrid`), whose
    setup is a sparse product and a small factorisation instead of a hierarchy (6x less). Either is
    rebuilt when a solve needed more than 30 (two-grid: 12) steps: a re-weighting that cut the
    surface at its jumps leaves the first one a poor preconditioner (dozens of steps, not ten).
    """

    def __init__(self, cell: NDArray | None = None) -> None:
        self.pre, self.cell = None, cell
        self.rebuild = 30 if cell is None else 12  # the two-grid setup is cheap: rebuilt sooner

    def __call__(self, a, b: NDArray[np.float64], x0: NDArray[np.float64], rtol: float) -> NDArray[np.float64]:
        import pyamg  # noqa: PLC0415
        from scipy.sparse.linalg import cg, spsolve  # noqa: PLC0415

        if a.shape[0] <= _DIRECT:  # small: a sparse direct solve beats building and running a hierarchy
            return spsolve(a.tocsc(), b)
        if self.cell is not None:
            self.pre = self.pre or _TwoGrid(a, self.cell)
            pre = self.pre.preconditioner(a)
        else:
            self.pre = self.pre or pyamg.smoothed_aggregation_solver(a, symmetry="symmetric", max_coarse=500)
            pre = self.pre.aspreconditioner()
        steps = [0]

        def count(_x) -> None:
            steps[0] += 1

        x, _ = cg(a, b, x0=x0, rtol=rtol, atol=0.0, maxiter=500, M=pre, callback=count)
        if steps[0] > self.rebuild:
            self.pre = None
        return x


class _TwoGrid:
    """Two-grid preconditioner: Gauss-Seidel sweeps and a direct solve for the per-cell constant part.

    ``P`` maps each cell's value to its pixels; the Galerkin system ``P^T A P`` of the system it is
    built on (a weighted Laplacian on the cells, as sparse as ``A``) is factorised once. One cycle
    is a forward sweep, the cells' correction of the residual and a backward sweep: symmetric,
    as conjugate gradients need. The sweeps remove the error that changes from pixel to pixel, the
    cells' solve the error that spans the object.
    """

    def __init__(self, a, cell: NDArray) -> None:
        from scipy import sparse  # noqa: PLC0415
        from scipy.sparse.csgraph import connected_components  # noqa: PLC0415
        from scipy.sparse.linalg import splu  # noqa: PLC0415

        # Cells cut where the re-weighting cut the surface: each connected piece of a cell's pixels
        # (over its edges of weight >= _STRONG) is its own constant, so no constant spans a depth jump.
        c = a.tocoo()
        keep = (c.row < c.col) & (-c.data >= _STRONG) & (cell[c.row] == cell[c.col])
        n = cell.size
        strong = sparse.csr_matrix((np.ones(int(keep.sum())), (c.row[keep], c.col[keep])), shape=(n, n))
        self.cells, self.cell = connected_components(strong, directed=False)
        p = sparse.csr_matrix((np.ones(n), (np.arange(n), self.cell)), shape=(n, self.cells))
        self.lu = splu((p.T @ a @ p).tocsc())

    def preconditioner(self, a):
        """The cycle for system ``a`` (a ``LinearOperator``)."""
        from pyamg.relaxation.relaxation import gauss_seidel  # noqa: PLC0415
        from scipy.sparse.linalg import LinearOperator  # noqa: PLC0415

        def cycle(r: NDArray) -> NDArray:
            x = np.zeros_like(r)
            gauss_seidel(a, x, r, iterations=1, sweep="forward")
            x += self.lu.solve(np.bincount(self.cell, r - a @ x, self.cells))[self.cell]
            gauss_seidel(a, x, r, iterations=1, sweep="backward")
            return x

        return LinearOperator(a.shape, matvec=cycle, dtype=np.float64)


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
    reweight_rtol: float = 1e-4,
    cell: int | None = None,
) -> NDArray[np.float32]:
    """Depth (m along the viewing axis) of the surface whose normals are ``normal`` on ``mask``.

    Only the mask's bounding box is worked on. The re-weighting stops early once a solve moves no
    pixel's log depth by more than ``settle`` (a relative depth change: 1e-4 is 0.075 mm at 0.75 m).
    Each part of the mask that is not connected to the others gets mean log depth 0 before the
    common scale (what the ``anchor`` term alone gives when solved exactly).

    The solves that only set the next weights stop at ``reweight_rtol``; the last system (the answer's
    weights) is then solved on to ``rtol`` from there. Where the re-weighting settles, the weights end on
    the sides that all-``rtol`` solves choose, and the depth with them; where it does not (it keeps moving
    the side a pixel trusts), the path differs, as it already does between any two tolerances.

    Each solve is conjugate gradients, preconditioned by a two-grid cycle on cells of
    ``cell`` x ``cell`` pixels (:func:`auto_cell` by default; a setup about 6x cheaper than
    algebraic multigrid's on a capture-sized mask), or by algebraic multigrid with ``cell=1`` (the
    route before 2026-11-27): the same systems to the same tolerance, so the same depth.

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
        rtol: relative residual at which the last conjugate-gradient solve stops.
        settle: stop re-weighting when a solve changed no log depth by more than this.
        reweight_rtol: relative residual at which the solves before the last stop; a value <= ``rtol``
            solves every system to ``rtol`` (the route before 2026-11-27's last change).
        cell: side in pixels of the two-grid preconditioner's cells; 1: algebraic multigrid; None:
            :func:`auto_cell` of the mask's pixel count.

    Returns:
        ``(H, W)`` float32 depth, positive and finite on the mask, 0 elsewhere.

    Raises:
        ValueError: bad shapes, a non-positive distance, a cell side below 1 or an empty mask.

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
    if cell is not None and (int(cell) != cell or cell < 1):
        raise ValueError(f"cell must be a whole number >= 1 or None; got {cell!r}")
    if not m.any():
        raise ValueError("the mask is empty: nothing to integrate")
    rows, cols = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
    y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    k = np.array(intrinsics, dtype=np.float64)
    k[0, 2] -= x0  # the crop's own pixel grid
    k[1, 2] -= y0
    side = auto_cell(int(m.sum())) if cell is None else int(cell)
    settings = _Settings(iterations, tau, min_cos, anchor, rtol, settle, reweight_rtol, side)
    z = _solve(n[y0:y1, x0:x1], m[y0:y1, x0:x1], k, settings)
    inside = m[y0:y1, x0:x1]
    z -= np.median(z[inside])
    depth = np.zeros(m.shape, np.float32)
    depth[y0:y1, x0:x1][inside] = distance * np.exp(np.clip(z[inside], -50.0, 50.0))
    return depth


def auto_cell(pixels: int) -> int:
    """:func:`integrate_normals`'s default cell side (two-grid preconditioner) for a mask of ``pixels`` pixels.

    About ``pixels / 16`` cells but at most 40,000 (their factorisation stays a fraction of a second).

    Example:
        >>> auto_cell(40_000), auto_cell(640_000), auto_cell(2_500_000)
        (4, 4, 8)
    """
    side = 4
    while pixels > _CELLS * side * side:
        side *= 2
    return side


# The two-grid preconditioner's cells number at most about this many (auto_cell).
_CELLS = 40_000
# Edges lighter than this (of about 1 on a smooth surface) cut a two-grid cell into pieces.
_STRONG = 0.1


@dataclass(frozen=True)
class _Settings:
    iterations: int
    tau: float
    min_cos: float
    anchor: float
    rtol: float
    settle: float
    reweight_rtol: float
    cell: int = 1


class _Grid:
    """The unknowns and 4-neighbour edges of a mask, and the normal equations' sparsity pattern.

    Each edge ``e`` (``q`` right of or below ``p``) holds one weighted equation ``z_q - z_p = t_e``;
    the normal equations are a weighted graph Laplacian ``D^T W D`` plus the anchor, assembled by
    placing values into a fixed CSR pattern (a sparse product per re-weighting costs 10x more).
    A pixel's trust in its "after" edge along each axis is a flat ``(2 n,)`` array (axis-major).
    """

    def __init__(self, m: NDArray[np.bool_]) -> None:
        from scipy import sparse  # noqa: PLC0415

        h, w = m.shape
        self.cols = np.flatnonzero(m.ravel())
        where = np.full(h * w, -1, np.int64)
        where[self.cols] = np.arange(self.cols.size)
        p, q, axis = _edges(m)
        self.p, self.q, self.axis = p, q, axis  # flat pixel indices in the box
        self.ip, self.iq = where[p], where[q]
        n, e = self.cols.size, p.size
        self.fp, self.fq = axis * n + self.ip, axis * n + self.iq  # p's after-trust, q's (this edge is q's before)
        # For every pixel and axis, the edge before it and the edge after it (-1: none).
        after, before = np.full(2 * n, -1, np.int64), np.full(2 * n, -1, np.int64)
        after[self.fp], before[self.fq] = np.arange(e), np.arange(e)
        self.has_after = after >= 0
        self.two = np.flatnonzero(self.has_after & (before >= 0))  # pixels (and axes) with an edge on both sides
        self.two_after, self.two_before = after[self.two], before[self.two]
        rows = np.concatenate([self.ip, self.iq, np.arange(n)])
        cols = np.concatenate([self.iq, self.ip, np.arange(n)])
        # Entry numbers as values: after the conversion to CSR, data[j] - 1 says which entry sits at j.
        pattern = sparse.csr_matrix((np.arange(1.0, rows.size + 1), (rows, cols)), shape=(n, n))
        self.at = np.empty(rows.size, np.int64)
        self.at[pattern.data.astype(np.int64) - 1] = np.arange(rows.size)  # where each entry goes
        self.indices, self.indptr = pattern.indices, pattern.indptr

    def matrix(self, weight: NDArray, anchor: float):
        """CSR ``D^T W D + anchor I`` for edge weights ``weight``."""
        from scipy import sparse  # noqa: PLC0415

        n, e = self.cols.size, weight.size
        data = np.empty(self.at.size)
        data[self.at[:e]] = data[self.at[e : 2 * e]] = -weight
        data[self.at[2 * e :]] = np.bincount(self.ip, weight, n) + np.bincount(self.iq, weight, n) + anchor
        return sparse.csr_matrix((data, self.indices, self.indptr), shape=(n, n))

    def rhs(self, weight: NDArray, target: NDArray) -> NDArray:
        """``D^T W t``."""
        wt = weight * target
        return np.bincount(self.iq, wt, self.cols.size) - np.bincount(self.ip, wt, self.cols.size)

    def equations(self, trust: NDArray, grad: tuple[NDArray, NDArray]) -> tuple[NDArray, NDArray]:
        """Edge weights and targets from each pixel's trust in its "after" edge.

        Each edge holds two one-sided equations, ``z_q - z_p = g(p)`` ("after p") and ``= g(q)``
        ("before q"); a pixel splits its trust between its two sides by how much the depth jumps on
        each (a pixel without an after edge has trust 0 in it: all on its before edge).
        """
        wf, wb = trust[self.fp], 1.0 - trust[self.fq]
        weight = np.maximum(wf + wb, 1e-8)
        return weight, (wf * grad[0] + wb * grad[1]) / weight

    def trust(self, z: NDArray, trust: NDArray, tau: float) -> NDArray:
        """Re-weighted trust of every two-sided pixel, from the squared log-depth steps of ``z`` on its sides.

        The side whose step is larger gets ``sigmoid((step_other^2 - step_this^2) / tau^2)``.
        """
        step = z[self.iq] - z[self.ip]
        jump = (step[self.two_after] ** 2 - step[self.two_before] ** 2) / tau**2
        out = trust.copy()
        out[self.two] = 1.0 / (1.0 + np.exp(np.clip(jump, -50.0, 50.0)))
        return out

    def initial_trust(self) -> NDArray:
        """Half on each side where a pixel has two, all on the one it has."""
        out = self.has_after.astype(np.float64)
        out[self.two] = 0.5
        return out


def _solve(n: NDArray[np.float64], m: NDArray[np.bool_], k: NDArray[np.float64], s: _Settings) -> NDArray[np.float64]:
    """``(H, W)`` log depth on ``m`` (0 elsewhere): the re-weighted least-squares solves."""
    gu, gv = log_depth_gradients(np.where(m[..., None], n, [0.0, 0.0, 1.0]), k, min_cos=s.min_cos)
    return _solve_gradients(gu, gv, m, s)


def _solve_gradients(gu: NDArray, gv: NDArray, m: NDArray[np.bool_], s: _Settings) -> NDArray[np.float64]:
    """``(H, W)`` log depth on ``m`` from per-pixel log-depth gradients: every solve at this resolution."""
    h, w = m.shape
    out = np.zeros(h * w)
    grid = _Grid(m)
    if grid.p.size == 0:  # isolated pixels: nothing relates their depths
        return out.reshape(h, w)
    grad = _edge_gradients(grid, gu, gv)
    reg = s.anchor
    trust = grid.initial_trust()
    z = np.zeros(grid.cols.size)
    cell = None
    if s.cell > 1:  # numbered cells of side s.cell, per unknown
        y, x = np.divmod(grid.cols, w)
        cell = np.unique((y // s.cell) * -(-w // s.cell) + x // s.cell, return_inverse=True)[1]
    solve = _Solver(cell)
    loose = max(s.rtol, s.reweight_rtol)
    for it in range(max(1, s.iterations)):
        weight, target = grid.equations(trust, grad)
        a, b = grid.matrix(weight, reg), grid.rhs(weight, target)
        z, previous = solve(a, b, z, loose), z
        if it + 1 == s.iterations or (it > 0 and np.abs(z - previous).max() <= s.settle):
            break
        trust = grid.trust(z, trust, s.tau)
    if loose > s.rtol and z.size > _DIRECT:  # loose solves only chose the weights: the answer's system to rtol
        z = solve(a, b, z, s.rtol)
    out[grid.cols] = _centre_parts(z, grid, m)
    return out.reshape(h, w)


def _edge_gradients(grid: _Grid, gu: NDArray, gv: NDArray) -> tuple[NDArray, NDArray]:
    """Each edge's gradient along its axis at ``p`` and at ``q``."""
    gu, gv, axis = gu.ravel(), gv.ravel(), grid.axis
    return np.where(axis == 0, gu[grid.p], gv[grid.p]), np.where(axis == 0, gu[grid.q], gv[grid.q])


def _centre_parts(z: NDArray, grid: _Grid, m: NDArray[np.bool_]) -> NDArray:
    """``z`` with each part of the mask (no edge between parts) at mean 0: the anchor's exact answer."""
    from scipy.ndimage import label  # noqa: PLC0415

    parts, count = label(m)
    part = parts.ravel()[grid.cols] - 1
    return z - (np.bincount(part, z, count) / np.bincount(part, minlength=count))[part]
