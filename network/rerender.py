"""Differentiable re-rendering of the unpol and LP maps under the display (the real-data loss).

Real captures have no ground truth, so the predicted maps are checked by rendering what the
camera would have seen and comparing with the decoded unpol and LP maps
(:func:`network.losses.real_loss`), with the diffuse and specular parts of
:func:`pbrdf.brdf.disney.disney_lobes`.

Model. A surface point ``p`` (camera frame, camera at the origin) with normal ``n`` is lit by
display patches ``k`` (centre ``y_k``, front normal ``n_k``, area ``A_k``, emitted radiance
``L_k`` per colour channel; :func:`display_patches`, each channel's lit region tiled on its own
by :func:`pbrdf.sensor.patches.channel_patches`). Per colour channel ``c``

.. math::
    s_{0,c} = \\sum_k (f_{d,c} + f_{s,c})(l_k, v)\\, L_{k,c}\\, (-n_k \\cdot l_k)_+^{m}\\, (n \\cdot l_k)_+\\,
              \\frac{A_k\\, (-n_k \\cdot l_k)_+}{\\lVert y_k - p \\rVert^2}

with ``l_k = (y_k - p) / |y_k - p|``, ``v = -p / |p|`` and ``m`` the display's emission profile
exponent (``cos^m`` of the emission angle, :mod:`pbrdf.sensor.display_response`; 0 = flat). The
diffuse lobe depolarizes; the specular lobe keeps the display's linear polarization (a mirror at
normal incidence), so with the per-patch gain ``g_k = -q cos 2 psi_k`` (``q`` the degree of
polarization, ``psi`` the angle of the field seen by the camera; 1 for the default vertical display)

.. math::
    \\mathrm{unpol}_c = D_c + \\sum_k (1 - g_k) S_{k,c},\\qquad \\mathrm{LP}_c = \\sum_k g_k S_{k,c}

(``D``, ``S_k`` the diffuse and specular terms of the sum). A specular lobe narrower than a patch
is widened per pixel and patch, ``alpha_eff^2 = alpha^2 + kappa Omega_k`` (:data:`WIDEN`,
``Omega_k`` the patch's solid angle), so the quadrature converges to the exact integral as the
patches shrink. What the approximation leaves out, the widening's derivation and the measured
accuracy: docs/measurements/network.md, "Re-renderer".

Convention: rays and intrinsics follow :mod:`pbrdf.sensor.projection` (OpenGL camera frame, pixel
centres at ``i + 0.5``); a point at depth ``z`` (along the viewing axis, as the dataset's
``depth``) is ``z`` times its pixel's ray (:func:`points_from_depth`). Values and gradients are
finite for any input.

Example:
    A rough grey point facing the camera 0.7 m away shows mostly unpol, a metal one only LP:

    >>> from pbrdf.sensor.rig import Rig
    >>> patches = display_patches(Rig(), (4, 4))
    >>> n, p = torch.tensor([[[0.0], [0.0], [1.0]]]), torch.tensor([[[0.0], [0.0], [-0.7]]])  # (B, 3, P)
    >>> albedo = torch.full((1, 3, 1), 0.5)
    >>> rough = rerender(n, albedo, torch.ones(1, 1, 1), torch.zeros(1, 1, 1), p, patches)
    >>> bool((rough["lp"] < 0.05 * rough["unpol"]).all())
    True
    >>> metal = rerender(n, albedo, torch.full((1, 1, 1), 0.3), torch.ones(1, 1, 1), p, patches)
    >>> metal["unpol"].abs().max().item(), bool((metal["lp"] > 0).all())
    (0.0, True)
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from torch import Tensor
from torch.utils.checkpoint import checkpoint

from pbrdf.brdf.disney import disney_lobes, roughness_to_alpha
from pbrdf.polar.fresnel import dielectric_transmittance
from pbrdf.sensor import projection
from pbrdf.sensor.patches import channel_patches

if TYPE_CHECKING:
    from pbrdf.sensor.rig import Rig

__all__ = [
    "PATCH_COLUMNS",
    "WIDEN",
    "DEFAULT_PATCHES",
    "DIFFUSE_MODELS",
    "PLASTIC_IOR",
    "Patches",
    "display_patches",
    "pixel_rays",
    "points_from_depth",
    "rerender",
    "rerender_dense",
]

#: Columns of a packed patch tensor ``(..., N, 11)``: centre (camera frame, m), unit front normal
#: (camera frame), area (m^2), emitted radiance per colour channel (along the normal), LP gain ``g``, the
#: emission profile's exponent.
PATCH_COLUMNS = ("x", "y", "z", "nx", "ny", "nz", "area", "radiance_r", "radiance_g", "radiance_b", "lp_gain",
                 "emission_exponent")  # fmt: skip
#: Lobe widening ``kappa``: ``alpha_eff^2 = alpha^2 + kappa * patch solid angle`` (module docs).
WIDEN = 1.0 / 24.0
#: Default patches per colour region ``(nx, ny)``: 3 x 144 = 432 patches (module docs for the accuracy).
DEFAULT_PATCHES = (12, 12)
#: Diffuse lobes: ``"burley"`` (Disney, the training loss's) or ``"fresnel"`` (Lambert times the
#: dielectric Fresnel transmission in and out, as Mitsuba's ``pplastic`` that renders the data).
DIFFUSE_MODELS = ("burley", "fresnel")
#: Refractive index of the ``"fresnel"`` diffuse lobe's coating (the renderer's ``pplastic`` default).
PLASTIC_IOR = 1.5

_EPS = 1e-12


class Patches(NamedTuple):
    """Display patches in the camera frame; leading batch dims ``*`` optional.

    Attributes:
        points: ``(*, N, 3)`` patch centres in m.
        normals: ``(*, N, 3)`` unit front normals (pointing toward the objects).
        area: ``(*, N)`` areas in m^2.
        radiance: ``(*, N, 3)`` emitted radiance per colour channel along the normal (renderer units).
        lp_gain: ``(*, N)`` ``g = -q cos 2 psi``: the fraction of a specular reflection that the
            decoder reads as LP (1 for fully, vertically polarized light).
        emission_exponent: ``(*, N)`` the radiance falls as ``cos^m`` of the emission angle (0: flat).
    """

    points: Tensor
    normals: Tensor
    area: Tensor
    radiance: Tensor
    lp_gain: Tensor
    emission_exponent: Tensor

    def pack(self) -> Tensor:
        """One tensor ``(*, N, 12)`` in :data:`PATCH_COLUMNS` order (collates with ``torch.stack``)."""
        scalars = [self.area[..., None], self.radiance, self.lp_gain[..., None], self.emission_exponent[..., None]]
        return torch.cat([self.points, self.normals, *scalars], -1)

    @classmethod
    def unpack(cls, packed: Tensor) -> Patches:
        """Inverse of :meth:`pack`.

        Raises:
            ValueError: if the last dimension is not 12.
        """
        if packed.shape[-1] != len(PATCH_COLUMNS):
            raise ValueError(f"packed patches must have shape (*, N, {len(PATCH_COLUMNS)}); got {tuple(packed.shape)}")
        return cls(
            packed[..., 0:3], packed[..., 3:6], packed[..., 6], packed[..., 7:10], packed[..., 10], packed[..., 11]
        )


def display_patches(
    rig: Rig,
    n: tuple[int, int] = DEFAULT_PATCHES,
    *,
    supersample: int = 4,
    dtype: torch.dtype = torch.float32,
) -> Patches:
    """Quadrature patches of the display, per colour channel region, in the camera frame.

    :func:`pbrdf.sensor.patches.channel_patches` (channel ``c``'s lit rectangle in ``nx x ny``
    equal patches carrying only channel ``c``, radiance averaged over ``supersample^2`` points of
    the patch) moved into the camera frame, with the LP gain of each patch.

    Args:
        rig: the capture rig (display geometry, pattern, polarization; camera pose).
        n: ``(nx, ny)`` patches per region along the display's X (width) and Y (height).
        supersample: pattern samples per patch and axis.
        dtype: float dtype of the tensors.

    Returns:
        :class:`Patches` with ``N = 3 nx ny`` (channel-major).

    Raises:
        ValueError: if ``n`` or ``supersample`` is not positive.
    """
    disp, cam = rig.display, rig.camera
    patches = channel_patches(disp, n, supersample=supersample)
    w2c = cam.world_to_camera()
    rot = w2c[:3, :3]
    y_world = disp.world_trans_display()[:, 1]
    a = disp.polarization_angle
    # The panel's X tangent (Y x normal) carries the in-plane polarization direction on a curved panel too.
    tangent = np.cross(y_world, patches.normals)
    e = (math.cos(a) * tangent + math.sin(a) * y_world) @ rot.T
    cos2psi = (e[:, 0] ** 2 - e[:, 1] ** 2) / np.maximum(e[:, 0] ** 2 + e[:, 1] ** 2, _EPS)

    def t(x: NDArray) -> Tensor:
        return torch.as_tensor(x, dtype=dtype)

    return Patches(
        t(patches.centers @ rot.T + w2c[:3, 3]),
        t(patches.normals @ rot.T),
        t(patches.area),
        t(patches.radiance),
        t(-disp.degree_of_polarization * cos2psi),
        t(np.full(len(patches), disp.emission_exponent)),
    )


def pixel_rays(intrinsics: ArrayLike, height: int, width: int, *, dtype: torch.dtype = torch.float32) -> Tensor:
    """Camera-frame rays ``(3, H, W)`` through the pixel centres, scaled to ``z = -1``.

    Channel-first :func:`pbrdf.sensor.projection.pixel_rays`: a point at depth ``z`` (m, along the
    viewing axis) is ``z * ray``.
    """
    rays = projection.pixel_rays(intrinsics, height, width)
    return torch.as_tensor(np.ascontiguousarray(np.moveaxis(rays, -1, 0)), dtype=dtype)


def points_from_depth(depth: Tensor, intrinsics: ArrayLike) -> Tensor:
    """Camera-frame points ``(*, 3, H, W)`` from depth ``(*, 1, H, W)`` (m along the viewing axis)."""
    h, w = depth.shape[-2:]
    return depth * pixel_rays(intrinsics, h, w, dtype=depth.dtype).to(depth.device)


def _safe_normalize(x: Tensor) -> Tensor:
    return x * torch.rsqrt((x * x).sum(-1, keepdim=True).clamp_min(_EPS))


def _shade(
    normal: Tensor,
    albedo: Tensor,
    roughness: Tensor,
    metallic: Tensor,
    points: Tensor,
    patches: Patches,
    widen: float,
    diffuse: str = "burley",
) -> tuple[Tensor, Tensor]:
    """``(unpol, lp)`` sums over the patches; pixel-last inputs ``(B, P, C)`` -> ``(B, P, 3)`` each."""
    p = points[:, :, None, :]  # (B, P, 1, 3)
    to = patches.points[:, None] - p  # (B, P, N, 3)
    d2 = (to * to).sum(-1).clamp_min(_EPS)
    l_dir = to * torch.rsqrt(d2)[..., None]
    v = _safe_normalize(-p)
    n = _safe_normalize(normal)[:, :, None, :]
    cos_e = (-(l_dir * patches.normals[:, None]).sum(-1)).clamp_min(0.0)
    solid = patches.area[:, None] * cos_e / d2  # (B, P, N) sr, 0 for back-facing patches
    cos_i = (n * l_dir).sum(-1).clamp_min(0.0)
    rough = roughness[..., 0][:, :, None]
    spec_rough = None
    if widen > 0:
        alpha = roughness_to_alpha(rough)
        spec_rough = (alpha * alpha + widen * solid).sqrt().sqrt()  # alpha_eff = spec_rough^2 >= alpha > 0
    fd, fs = disney_lobes(
        n, l_dir, v, albedo[:, :, None, :], rough, metallic[..., 0][:, :, None], specular_roughness=spec_rough
    )
    if diffuse == "fresnel":  # pplastic: Lambert attenuated by the coating's smooth refraction in and out
        cos_o = (n * v).sum(-1).clamp_min(0.0)
        t = dielectric_transmittance(cos_i, PLASTIC_IOR) * dielectric_transmittance(cos_o, PLASTIC_IOR) * (cos_o > 0)
        fd = albedo[:, :, None, :] * ((1.0 - metallic[..., 0][:, :, None]) * t / math.pi)[..., None]
    m = patches.emission_exponent[:, None]
    profile = torch.where(m == 0, 1.0, cos_e.clamp_min(_EPS) ** m)  # the flat display's sums unchanged
    light = patches.radiance[:, None] * (cos_i * solid * profile)[..., None]  # (B, P, N, 3)
    diffuse = (fd * light).sum(2)
    spec = fs * light
    lp = (spec * patches.lp_gain[:, None, :, None]).sum(2)
    return diffuse + spec.sum(2) - lp, lp


def _batched(patches: Patches, batch: int) -> Patches:
    if patches.points.ndim == 2:
        return Patches(*(x.expand(batch, *x.shape) for x in patches))
    return patches


def rerender(
    normal: Tensor,
    albedo: Tensor,
    roughness: Tensor,
    metallic: Tensor,
    points: Tensor,
    patches: Patches,
    *,
    widen: float = WIDEN,
    chunk: int = 256,
    diffuse: str = "burley",
) -> dict[str, Tensor]:
    """Re-render the unpol (diffuse) and LP (specular) maps at P pixels under the display.

    Args:
        normal: ``(B, 3, P)`` camera-frame normals (OpenGL axes); renormalised here.
        albedo: ``(B, 3, P)`` base colour, linear RGB in [0, 1].
        roughness: ``(B, 1, P)`` perceptual roughness in [0, 1] (GGX alpha = roughness^2).
        metallic: ``(B, 1, P)`` in [0, 1].
        points: ``(B, 3, P)`` camera-frame surface points in m (camera at the origin).
        patches: :class:`Patches` of shape ``(N, .)`` (shared) or ``(B, N, .)``.
        widen: lobe widening ``kappa`` (module docs); 0 evaluates the plain lobe at the centres.
        chunk: pixels per evaluation block (memory ``~ B chunk N`` floats per intermediate).
        diffuse: the diffuse lobe, one of :data:`DIFFUSE_MODELS`.

    Returns:
        ``{"unpol": (B, 3, P), "lp": (B, 3, P)}`` in the display's radiance units.

    Raises:
        ValueError: on mismatched shapes or an unknown ``diffuse``.
    """
    if diffuse not in DIFFUSE_MODELS:
        raise ValueError(f"diffuse must be one of {', '.join(DIFFUSE_MODELS)}; got {diffuse!r}")
    b, _, p = normal.shape
    for name, x, c in (("normal", normal, 3), ("albedo", albedo, 3), ("roughness", roughness, 1),
                       ("metallic", metallic, 1), ("points", points, 3)):  # fmt: skip
        if x.shape != (b, c, p):
            raise ValueError(f"{name} must have shape (B, {c}, P) = {(b, c, p)}; got {tuple(x.shape)}")
    pt = _batched(patches, b)
    if pt.points.shape[0] != b:
        raise ValueError(f"patches have batch {pt.points.shape[0]}, the maps {b}")
    dtype = torch.promote_types(normal.dtype, torch.float32)
    pt = Patches(*(x.to(device=normal.device, dtype=dtype) for x in pt))
    args = [x.to(dtype).transpose(1, 2) for x in (normal, albedo, roughness, metallic, points)]
    # Under autograd each block is recomputed in the backward pass (checkpointing), so memory stays at
    # one block's intermediates instead of B x P x N x 3 times dozens of tensors.
    grad = torch.is_grad_enabled() and any(x.requires_grad for x in (normal, albedo, roughness, metallic, points))
    unpol, lp = [], []
    for s in range(0, p, chunk):
        block = [x[:, s : s + chunk] for x in args]
        if grad:
            u, q = checkpoint(_shade, *block, pt, widen, diffuse, use_reentrant=False)
        else:
            u, q = _shade(*block, pt, widen, diffuse)
        unpol.append(u)
        lp.append(q)
    return {"unpol": torch.cat(unpol, 1).transpose(1, 2), "lp": torch.cat(lp, 1).transpose(1, 2)}


def rerender_dense(
    pred: dict[str, Tensor],
    mask: Tensor,
    points: Tensor,
    patches: Patches,
    *,
    widen: float = WIDEN,
    chunk: int = 4096,
    diffuse: str = "burley",
) -> dict[str, Tensor]:
    """Re-render full unpol and LP maps from dense predicted maps (evaluation).

    Args:
        pred: ``normal (B, 3, H, W)``, ``albedo (B, 3, H, W)``, ``roughness (B, 1, H, W)``,
            ``metallic (B, 1, H, W)`` (e.g. the model's eval-mode output).
        mask: ``(B, 1, H, W)`` pixels to render; the rest is 0.
        points: ``(B, 3, H, W)`` camera-frame surface points (:func:`points_from_depth`).
        patches: :class:`Patches`, ``(N, .)`` or ``(B, N, .)``.
        widen: see :func:`rerender`.
        chunk: pixels per block.
        diffuse: see :func:`rerender`.

    Returns:
        ``{"unpol": (B, 3, H, W), "lp": (B, 3, H, W)}``, zero outside the mask. Runs under the
        caller's grad mode (wrap in ``torch.no_grad()`` for evaluation).
    """
    b, _, h, w = mask.shape
    flat = {k: pred[k].reshape(b, pred[k].shape[1], h * w) for k in ("normal", "albedo", "roughness", "metallic")}
    out = rerender(
        **flat, points=points.reshape(b, 3, h * w), patches=patches, widen=widen, chunk=chunk, diffuse=diffuse
    )
    m = mask.reshape(b, 1, h * w).to(out["unpol"].dtype)
    return {k: (v * m).reshape(b, 3, h, w) for k, v in out.items()}
