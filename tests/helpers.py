"""Plain helper functions shared by several test modules (fixtures live in tests/conftest.py).

Import as ``from tests.helpers import random_hemisphere`` (the repository root is on the path).
"""

import math

import numpy as np

from pbrdf.sensor.camera import CameraModel

#: Grid of the small synthetic dataset samples made by :func:`make_sample`.
H, W = 4, 6


def random_hemisphere(rng, n, min_cos=0.0):
    """Unit vectors uniform on the upper hemisphere with ``z > min_cos``."""
    z = rng.uniform(min_cos, 1.0, n)
    phi = rng.uniform(0, 2 * math.pi, n)
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=-1)


def make_sample(rng, *, stokes=False, raw=False):
    """A valid sample on an (H, W) grid and its metadata."""
    mask = rng.random((H, W)) > 0.3
    mask[0, 0], mask[0, 1] = True, False
    n = rng.normal(size=(H, W, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    sample = {
        "maps": rng.normal(size=(H, W, 9)).astype(np.float32),
        "mask": mask,
        "normal": np.where(mask[..., None], n, 0).astype(np.float32),
        "albedo": rng.uniform(0, 1, (H, W, 3)).astype(np.float32),
        "roughness": rng.uniform(0, 1, (H, W)).astype(np.float32),
        "metallic": rng.uniform(0, 1, (H, W)).astype(np.float32),
        "depth": np.where(mask, rng.uniform(0.3, 2.0, (H, W)), 0).astype(np.float32),
    }
    sample["albedo"][0, 0] = [0.0, 1.0, 0.5]  # range ends are valid
    metadata = {
        "rig": {"camera": {"to_world": np.eye(4)}},  # numpy values become JSON lists
        "materials": [{"id": "gold", "disney": {"metallic": 1.0, "roughness": np.float64(0.25)}}],
        "seed": 1234,
        "versions": {"pbrdf": "0.1.0"},
    }
    if stokes:
        sample["stokes"] = rng.normal(size=(H, W, 3, 4)).astype(np.float32)
    if raw:
        model = CameraModel(exposures=(0.01, 0.04))
        base = rng.integers(16, 900, (2 * H, 2 * W))
        sample["raw"] = np.stack([base, np.minimum(4 * base, 4095)]).astype(np.uint16)
        metadata["camera_model"] = model.to_dict()
    return sample, metadata


def assert_samples_equal(got, want):
    assert sorted(got) == sorted(want)
    for key, arr in want.items():
        assert got[key].dtype == arr.dtype, key
        assert got[key].shape == arr.shape, key
        np.testing.assert_array_equal(got[key], arr, err_msg=key)
        if arr.dtype == np.float32:  # bit for bit (the test data has no -0.0, but say so anyway)
            np.testing.assert_array_equal(got[key].view(np.uint32), arr.view(np.uint32), err_msg=key)


# --------------------------------------------------------------------------- polarization

#: Unit Stokes vectors of the named polarization states (s1 > 0 horizontal, s3 > 0 right circular).
HORIZONTAL = [1.0, 1.0, 0.0, 0.0]
VERTICAL = [1.0, -1.0, 0.0, 0.0]
PLUS_45 = [1.0, 0.0, 1.0, 0.0]
MINUS_45 = [1.0, 0.0, -1.0, 0.0]
RIGHT_CIRCULAR = [1.0, 0.0, 0.0, 1.0]
LEFT_CIRCULAR = [1.0, 0.0, 0.0, -1.0]
UNPOLARIZED = [1.0, 0.0, 0.0, 0.0]


def random_stokes(rng, n):
    """Physical Stokes vectors, valid by construction: s0 in [0.1, 2], any DoP, AoLP and ellipticity."""
    from pbrdf.polar import stokes

    pi = np.pi
    return stokes.stokes(
        rng.uniform(0.1, 2.0, n), rng.uniform(0, 1, n), rng.uniform(0, pi, n), rng.uniform(-pi / 4, pi / 4, n)
    )


def disc_stokes(h: int, w: int, radius: float, *, level: float = 0.05, dark_patch: bool = False) -> np.ndarray:
    """Stokes images ``(h, w, 3, 4)``: a shaded, partly polarized disc on a black background.

    The disc's s0 falls off towards the limb (to 20 % of the centre, like a diffuse sphere), its
    polarized part is display light (``s1 = -0.3 s0``); ``dark_patch`` puts a patch at 0.2 % of
    the brightness (below the noise floor: dark metal) in its middle.
    """
    y, x = np.mgrid[0:h, 0:w] + 0.0
    r = np.hypot(y - h / 2, x - w / 2) / radius
    s0 = np.where(r < 1, level * (0.2 + 0.8 * np.sqrt(np.clip(1 - r**2, 0, 1))), 0.0)
    if dark_patch:
        s0 = np.where((np.abs(y - h / 2) < radius / 4) & (np.abs(x - w / 2) < radius / 3), 0.002 * s0, s0)
    st = np.zeros((h, w, 3, 4))
    for c, tint in enumerate((1.0, 0.8, 0.6)):
        st[..., c, 0] = tint * s0
        st[..., c, 1] = -0.3 * tint * s0
    return st


def assert_angles_close_mod_pi(actual, expected, atol):
    """Angles of linear polarization are defined modulo pi."""
    d = np.mod(np.asarray(actual) - np.asarray(expected) + np.pi / 2, np.pi) - np.pi / 2
    assert np.all(np.abs(d) <= atol), f"max angle error {np.max(np.abs(d))} > {atol}"


def assert_pure_mueller(m, atol):
    """Non-depolarizing (Mueller-Jones) matrices satisfy tr(M^T M) = 4 m00^2.

    J. J. Gil and E. Bernabeu, "A depolarization criterion in Mueller matrices", Optica Acta 32(3):259, 1985.
    """
    m = np.asarray(m)
    np.testing.assert_allclose(np.einsum("...ij,...ij->...", m, m), 4 * m[..., 0, 0] ** 2, atol=atol)


def assert_maps_physical_to_physical(m, rng):
    """Stokes criterion: physical input states give physical output states."""
    from pbrdf.polar import mueller, stokes

    s_in = random_stokes(rng, 64)
    s_out = mueller.apply(np.asarray(m)[..., None, :, :], s_in)
    assert np.all(stokes.is_physical_stokes(s_out, rtol=1e-9, atol=1e-12))


def assert_mueller_physical(m, rng):
    """The Cloude test of pbrdf.polar.validity (which implies Givens-Kostinski), plus the Stokes criterion done here."""
    from pbrdf.polar import validity

    assert np.all(validity.is_mueller_physical(m))
    assert_maps_physical_to_physical(m, rng)


def mi_matrix(m):
    """A Mitsuba matrix as a float64 numpy array."""
    return np.array(m, dtype=np.float64)


# --------------------------------------------------------------------------- polarization camera

#: The IMX250MYR 4x4 super-pixel, (row, col), row 0 at the top of the image.
IMX250MYR_LAYOUT = (
    ("R90", "R45", "G90", "G45"),
    ("R135", "R0", "G135", "G0"),
    ("G90", "G45", "B90", "B45"),
    ("G135", "G0", "B135", "B0"),
)
#: Camera-model options of ideal optics: perfect micro-polarizers and an exact quarter-wave plate.
IDEAL_OPTICS = {"extinction_ratio": np.inf, "qwp_retardance": np.pi / 2}


def parse_layout_entry(entry: str) -> tuple[int, int]:
    """'G135' -> (colour index in R, G, B; angle in degrees)."""
    return "RGB".index(entry[0]), int(entry[1:])


def elliptical_states() -> np.ndarray:
    """Three distinct fully polarized elliptical states (R, G, B), s2 != 0 included, shape (3, 4)."""
    from pbrdf.polar.stokes import stokes

    return stokes(1.0, 1.0, np.deg2rad([20.0, 75.0, 140.0]), np.deg2rad([12.0, -25.0, 33.0]))


# --------------------------------------------------------------------------- network models


def make_model(name="toy", seed=0, **overrides):
    """A seeded PolarInverseModel of configuration ``name`` in eval mode."""
    import torch

    from network.config import get_config
    from network.model.polar_model import PolarInverseModel

    torch.manual_seed(seed)
    return PolarInverseModel(get_config(name, **overrides)).eval()


def toy_model(seed=0, **overrides):
    """A seeded toy PolarInverseModel (left in training mode)."""
    import torch

    from network.config import get_config
    from network.model.polar_model import PolarInverseModel

    torch.manual_seed(seed)
    return PolarInverseModel(get_config("toy", **overrides))


def toy_train_config(data, out, **overrides):
    """A :class:`network.train.TrainConfig` of the toy model on the CPU (1e-3, seed 0, no TensorBoard)."""
    from network.train import TrainConfig

    base = {"config": "toy", "lr": 1e-3, "seed": 0, "checkpoint_every": 100, "tensorboard": False, "device": "cpu"}
    return TrainConfig(data=data, out=out, **{**base, **overrides})


def toy_inputs(batch=1, size=64, seed=1):
    """Random maps (B, 9, size, size) and a rectangular mask with a hole (B, 1, size, size)."""
    import torch

    g = torch.Generator().manual_seed(seed)
    maps = torch.rand(batch, 9, size, size, generator=g)
    mask = torch.zeros(batch, 1, size, size)
    mask[..., 8:56, 12:52] = 1.0
    mask[..., 20:24, 20:40] = 0.0  # a hole
    return maps, mask


# --------------------------------------------------------------------------- scene specs


def rigid_pose(t=(0.0, 0.0, 0.0), rot=None) -> np.ndarray:
    """4x4 pose with translation ``t`` and 3x3 block ``rot`` (identity if None)."""
    m = np.eye(4)
    if rot is not None:
        m[:3, :3] = rot
    m[:3, 3] = t
    return m


def rot_x(a: float) -> np.ndarray:
    """3x3 rotation by ``a`` radians about x."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], dtype=float)


# --------------------------------------------------------------------------- Blender (bpy imported on use)


def write_pbr_maps(folder, normal, *, albedo=None, mask=None, depth=None, roughness=None, prefix="cap"):
    """Write a PBR map folder (``<prefix>_normal.exr`` and the optional maps) for the add-on's importer."""
    from pbrdf.io.exr import write_exr

    folder.mkdir(parents=True, exist_ok=True)
    write_exr(folder / f"{prefix}_normal.exr", {f"normal.{c}": normal[..., i] for i, c in enumerate("XYZ")})
    if albedo is not None:
        write_exr(folder / f"{prefix}_albedo.exr", {f"albedo.{c}": albedo[..., i] for i, c in enumerate("RGB")})
    if mask is not None:
        write_exr(folder / f"{prefix}_mask.exr", {"mask.Y": mask.astype(np.float32)})
    if depth is not None:
        write_exr(folder / f"{prefix}_depth.exr", {"depth.Y": depth.astype(np.float32)}, allow_nonfinite=True)
    if roughness is not None:
        write_exr(folder / f"{prefix}_roughness.exr", {"roughness.Y": roughness.astype(np.float32)})
    return folder


def add_camera(scene, location=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0)):
    """A default camera ("Cam") linked to ``scene`` as its active camera; the view layer is updated."""
    import bpy

    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    cam.location, cam.rotation_euler = location, rotation
    bpy.context.view_layer.update()
    return cam


def add_render_camera(bpy, location, rotation=(0.0, 0.0, 0.0), *, res=(32, 32), lens=50.0):
    """The context scene's active camera ("Camera", focal length ``lens``) and its resolution ``res``."""
    scene = bpy.context.scene
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    cam.location, cam.rotation_euler = location, rotation
    cam.data.lens = lens
    scene.camera = cam
    scene.render.resolution_x, scene.render.resolution_y = res
    scene.render.resolution_percentage = 100
    return cam


def add_light(bpy, kind: str, location, rotation=(0.0, 0.0, 0.0), **props):
    """A light of type ``kind`` ("POINT", "SUN", ...) with data properties ``props`` in the context scene."""
    data = bpy.data.lights.new(kind.lower(), kind)
    for k, v in props.items():
        setattr(data, k, v)
    obj = bpy.data.objects.new(kind.lower(), data)
    bpy.context.scene.collection.objects.link(obj)
    obj.location, obj.rotation_euler = location, rotation
    return obj


def world_matrix(obj):
    """``obj.matrix_world`` (float64) after a view-layer update."""
    import bpy

    bpy.context.view_layer.update()
    return np.array(obj.matrix_world, dtype=np.float64)


def display_quadrature(display, point, normal=None, n=400):
    """Irradiance vectors (3, 3) (or, with ``normal``, the irradiance (3,)) by brute-force quadrature.

    The display's radiance is ``radiance * pattern * cos^p`` of the emission angle (``emission_exponent``).
    """
    xs = (np.arange(n) + 0.5) / n * display.width - display.width / 2
    ys = (np.arange(n // 2) + 0.5) / (n // 2) * display.height - display.height / 2
    xy = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)
    to = display.surface_points_world(xy) - point
    d2 = np.sum(to**2, -1)
    w = to / np.sqrt(d2)[:, None]
    cos_d = np.clip(-np.sum(w * display.surface_normals_world(xy), -1), 0, None)
    weight = cos_d ** (1.0 + display.emission_exponent) / d2 * display.width * display.height / len(xy)
    weight = weight * display.radiance
    rgb = display.pattern_rgb_at(xy)
    if normal is None:
        return np.einsum("pk,p,pc->ck", w, weight, rgb)
    return np.einsum("p,p,pc->c", np.clip(w @ normal, 0, None), weight, rgb)


def rusinkiewicz_pairs(rng, n, min_cos=0.02):
    """Direction pairs sampled like a measured-BRDF table: theta_h = (pi/2) u^2 concentrates on the peak.

    theta_d and phi_d uniform; pairs with a direction below ``min_cos`` are dropped (so fewer than n).
    """
    th = 0.5 * math.pi * rng.uniform(0, 1, n) ** 2
    ph = rng.uniform(0, 2 * math.pi, n)
    td = rng.uniform(0, 0.5 * math.pi, n)
    pd = rng.uniform(0, 2 * math.pi, n)
    h = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
    t = np.stack([-np.sin(ph), np.cos(ph), np.zeros(n)], axis=-1)  # perpendicular to h and to z
    b = np.cross(h, t)
    wi = (np.sin(td) * np.cos(pd))[:, None] * t + (np.sin(td) * np.sin(pd))[:, None] * b + np.cos(td)[:, None] * h
    wo = 2 * np.sum(wi * h, axis=-1, keepdims=True) * h - wi
    ok = (wi[:, 2] > min_cos) & (wo[:, 2] > min_cos)
    return wi[ok], wo[ok]
