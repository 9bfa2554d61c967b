"""Placement in view: a random pose 50-100 cm in front of the camera with the whole mesh inside its view.

Apart from :mod:`.assets` because it needs no mesh pipeline, only numpy and the rig: anything with
``vertices`` is placed (a trimesh, or the bounding-box corners the add-on's scene builder passes),
so it works in Blender's Python without trimesh. Sizes follow the convention of :mod:`.procedural`
(:func:`~.procedural.diameter`).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from pbrdf.sensor.rig import Rig

if TYPE_CHECKING:
    import trimesh

__all__ = ["place", "random_rotation"]


def random_rotation(rng: np.random.Generator) -> NDArray[np.float64]:
    """Rotation matrix ``(3, 3)`` uniform on SO(3): a normalised Gaussian quaternion (Shoemake 1992)."""
    q = rng.standard_normal(4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _range(value: Any, name: str) -> tuple[float, float]:
    lo, hi = (float(v) for v in value)
    if not 0 < lo <= hi or not math.isfinite(hi):
        raise ValueError(f"{name} must be (min, max) with 0 < min <= max, got {value!r}")
    return lo, hi


def place(
    mesh: trimesh.Trimesh,
    rig: Rig,
    rng: np.random.Generator,
    *,
    distance: tuple[float, float] = (0.5, 1.0),
    size: tuple[float, float] = (0.15, 0.35),
    margin: float = 0.03,
    max_tries: int = 100,
) -> NDArray[np.float64]:
    """Random pose of a mesh in front of the camera, fully inside its view.

    The rotation is uniform on SO(3), the :func:`~.procedural.diameter` uniform in ``size`` metres, and the
    bounding-box centre lies at a distance uniform in ``distance`` from the camera centre, on the
    ray through a pixel drawn uniformly among those that keep the object's bounding sphere
    inside the view. Every vertex then projects inside the sensor at least
    ``margin * min(W, H)`` pixels from each edge (checked exactly).

    Args:
        mesh: the object in its own units (any scale and position).
        rig: supplies the camera (its pose and intrinsics).
        rng: random generator; the same state gives the same pose.
        distance: (min, max) distance in m from the camera to the object's centre.
        size: (min, max) object diameter in m.
        margin: fraction of the shorter sensor side kept free on every edge.
        max_tries: draws of (rotation, size, distance) before giving up.

    Returns:
        ``to_world`` ``(4, 4)``: object coordinates to world (rotation times uniform scale plus
        translation).

    Raises:
        ValueError: bad ranges, or no pose found in ``max_tries`` (the object cannot fit at that
            size and distance).
    """
    d_lo, d_hi = _range(distance, "distance")
    s_lo, s_hi = _range(size, "size")
    if not 0 <= margin < 0.5:
        raise ValueError(f"margin must be in [0, 0.5), got {margin}")
    cam = rig.camera
    w, h, f = cam.sensor_width_px, cam.sensor_height_px, cam.focal_length_px
    margin_px = margin * min(w, h)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    centre = (v.min(axis=0) + v.max(axis=0)) / 2
    local = v - centre
    radius = float(np.sqrt(np.max(np.sum(local**2, axis=1))))
    if not radius > 0:
        raise ValueError("cannot place a mesh whose vertices all coincide")
    # Inward unit normals of the four side planes of the frustum shrunk by the margin (camera frame).
    tx = (w / 2 - margin_px) / f
    ty = (h / 2 - margin_px) / f
    planes = np.array([[-1.0, 0.0, -tx], [1.0, 0.0, -tx], [0.0, -1.0, -ty], [0.0, 1.0, -ty]])
    planes /= np.linalg.norm(planes, axis=1, keepdims=True)
    cam_to_world = cam.camera_to_world()
    candidates = 64
    for _ in range(int(max_tries)):
        rot = random_rotation(rng)
        scale = rng.uniform(s_lo, s_hi) / (2.0 * radius)
        dist = rng.uniform(d_lo, d_hi)
        u = rng.uniform(margin_px, w - margin_px, candidates)
        vv = rng.uniform(margin_px, h - margin_px, candidates)
        dirs = np.stack([(u - w / 2) / f, (h / 2 - vv) / f, -np.ones(candidates)], axis=-1)
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        sphere_ok = np.all(dirs @ planes.T >= scale * radius / dist, axis=1)
        # The bounding sphere inside the view implies every vertex is; without such a candidate
        # (a large object close by) test the vertices of every candidate.
        ks = np.flatnonzero(sphere_ok) if sphere_ok.any() else np.arange(candidates)
        pts_obj = local @ (scale * rot).T
        for k in ks:
            to_cam = np.eye(4)
            to_cam[:3, :3] = scale * rot
            to_cam[:3, 3] = dist * dirs[k] - to_cam[:3, :3] @ centre
            to_world = cam_to_world @ to_cam
            pts = pts_obj + dist * dirs[k]
            pts_world = pts @ cam_to_world[:3, :3].T + cam_to_world[:3, 3]
            if cam.out_of_view_px(pts_world, margin_px) <= 0:
                return to_world
    raise ValueError(
        f"place: no pose inside the view after {max_tries} tries "
        f"(size {size} m at distance {distance} m with a {margin:.0%} margin)"
    )
