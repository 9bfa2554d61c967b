"""Helpers of the textured-rendering tests: a slab with planar UVs, two-level PNG textures, regions."""

import math

import numpy as np


def uv_slab_file(folder):
    """A 0.3 m slab (PLY) facing +z with planar UVs: u = (x + 0.15) / 0.3, v = (y + 0.15) / 0.3."""
    import trimesh

    from blender_addon.core import assets

    box = trimesh.creation.box(extents=(0.3, 0.3, 0.01))
    for _ in range(4):
        box = box.subdivide()
    v = np.asarray(box.vertices)
    path = folder / "uv_slab.ply"
    assets.write_ply_arrays(path, v, np.asarray(box.faces), uvs=(v[:, :2] + 0.15) / 0.3)
    return str(path)


def png(folder, name, top, bottom, *, size=32, left=None):
    """A ``size`` x ``size`` 8-bit image: ``top`` over ``bottom`` (RGB or grey levels 0..255),
    or with ``left`` given, ``left`` | ``bottom`` side by side."""
    from PIL import Image

    img = np.zeros((size, size, 3), np.uint8)
    if left is None:
        img[: size // 2], img[size // 2 :] = top, bottom
    else:
        img[:, : size // 2], img[:, size // 2 :] = left, bottom
    path = folder / name
    Image.fromarray(img).save(path)
    return str(path)


def pose(tilt_deg=0.0, toward="x"):
    """The slab 0.6 m in front of the camera, its normal tilted by ``tilt_deg`` toward +x or +y."""
    c, s = math.cos(math.radians(tilt_deg)), math.sin(math.radians(tilt_deg))
    if toward == "x":
        m = np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, -0.6], [0, 0, 0, 1]])
    else:
        m = np.array([[1, 0, 0, 0], [0, c, s, 0], [0, -s, c, -0.6], [0, 0, 0, 1]])
    return tuple(map(tuple, m))


def halves(res, margin=0.2):
    """Inner pixels of the object's top and bottom halves."""
    rows, cols = np.nonzero(res.mask)
    r0, r1, c0, c1 = rows.min(), rows.max(), cols.min(), cols.max()
    h, w = r1 - r0, c1 - c0
    rr, cc = np.mgrid[: res.mask.shape[0], : res.mask.shape[1]]
    inner = res.mask & (cc > c0 + margin * w) & (cc < c1 - margin * w)
    top = inner & (rr > r0 + margin * h / 2) & (rr < r0 + h / 2 - margin * h / 2)
    bottom = inner & (rr > r0 + h / 2 + margin * h / 2) & (rr < r1 - margin * h / 2)
    return top, bottom
