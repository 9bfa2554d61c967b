"""Classical baseline: RGB photometric stereo from the display's three colour regions.

Each colour channel of the display lights the object from its own region (red: the display's
right half, green: the left half, blue: the upper half, as seen from the object), so the three
unpolarized (diffuse) maps are three images under three lights. With calibrated light
directions ``L`` (3x3, one unit vector per channel: from the object towards the centroid of that
channel's lit region, irradiance-weighted) and a Lambertian model ``I_c = rho_c / pi * E_c * (n
. l_c)``, the normal is ``n ~ L^-1 I`` (per pixel, with per-channel irradiance ``E_c``); the
albedo follows from ``|L^-1 I|``. Colour albedo and geometry are confounded for a single RGB
image: the baseline assumes a grey (achromatic) albedo for the normal, as classical colour
photometric stereo does, and reports the per-channel ratio as albedo.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["region_light_directions", "photometric_stereo"]


def region_light_directions(display, point: NDArray, *, samples: int = 64) -> tuple[NDArray, NDArray]:
    """Unit directions (3, 3) from ``point`` (world) to each colour region, and their irradiance scale (3,).

    Args:
        display: a :class:`pbrdf.sensor.rig.DisplaySpec`-like object with ``width``,
            ``height``, ``pattern_rgb_at(xy)``, ``surface_points_world(xy)`` and ``normal_world()``.
        point: ``(3,)`` a representative object point (e.g. its centre) in world coordinates.
        samples: quadrature resolution along the display's width.
    """
    n = samples
    xs = (np.arange(n) + 0.5) / n * display.width - display.width / 2
    ys = (np.arange(n // 2) + 0.5) / (n // 2) * display.height - display.height / 2
    gx, gy = np.meshgrid(xs, ys)
    xy = np.stack([gx.ravel(), gy.ravel()], -1)
    pts = display.surface_points_world(xy)
    rgb = display.pattern_rgb_at(xy)
    to = pts - np.asarray(point, dtype=np.float64)
    d2 = np.sum(to**2, -1)
    w = to / np.sqrt(d2)[:, None]
    cos_d = np.clip(-(w @ display.normal_world()), 0, None)
    weight = cos_d / d2  # irradiance contribution of each patch (times the patch area)
    dirs, scale = np.zeros((3, 3)), np.zeros(3)
    for c in range(3):
        v = (w * (weight * rgb[:, c])[:, None]).sum(0)
        scale[c] = np.linalg.norm(v) * display.width * display.height / len(xy)
        dirs[c] = v / max(np.linalg.norm(v), 1e-12)
    return dirs, scale


def photometric_stereo(unpol: NDArray, mask: NDArray, directions: NDArray, scale: NDArray) -> dict[str, NDArray]:
    """Lambertian RGB photometric stereo.

    Args:
        unpol: ``(H, W, 3)`` unpolarized maps (R, G, B) in radiance units.
        mask: ``(H, W)`` valid pixels.
        directions: ``(3, 3)`` unit light directions per channel, camera frame.
        scale: ``(3,)`` irradiance per channel (the length of the irradiance vector).

    Returns:
        ``normal (H, W, 3)`` unit, camera frame (0 outside the mask) and ``albedo (H, W, 3)`` in
        [0, 1].
    """
    i = np.asarray(unpol, dtype=np.float64) / np.maximum(scale, 1e-12) * np.pi  # rho (n . l_c)
    g = i @ np.linalg.inv(directions).T  # rho n, assuming a grey rho
    rho = np.linalg.norm(g, axis=-1)
    n = g / np.maximum(rho, 1e-12)[..., None]
    shading = np.clip(n @ directions.T, 1e-3, None)  # (H, W, 3): n . l_c
    albedo = np.clip(i / shading, 0.0, 1.0)
    m = np.asarray(mask, dtype=bool)
    n[~m], albedo[~m] = 0.0, 0.0
    return {"normal": n.astype(np.float32), "albedo": albedo.astype(np.float32)}
