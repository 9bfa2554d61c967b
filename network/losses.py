"""Training losses (masked), with zero-weight terms skipped.

Synthetic data: ``L = w_n |n - n*|^2 + w_a |a - a*|^2 + w_r (r - r*)^2 + w_m (m - m*)^2 + w_c (1 -
cos(a, a*))`` averaged over valid pixels; the last term is the albedo chromaticity loss (the angle
between predicted and true RGB albedo vectors, insensitive to the global scale that the display's
brightness cannot fix).

Real data (:func:`real_loss`, weight ``LossWeights.real``, 0 = off): the predicted maps are
re-rendered under the display (:mod:`network.rerender`) and compared with the observed unpol and
LP maps, up to one unknown scale per image (module docs of :func:`real_loss`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from .data import gather_pixels
from .rerender import Patches, rerender

__all__ = ["LossWeights", "synthetic_loss", "real_loss", "REAL_FLOOR"]

#: Floor of the per-map weights of :func:`real_loss`, as a fraction of the mean map energy.
REAL_FLOOR = 0.05


@dataclass(frozen=True)
class LossWeights:
    """Weights of the loss terms; a 0 weight skips the term entirely (no compute)."""

    normal: float = 1.0
    albedo: float = 1.0
    roughness: float = 1.0
    metallic: float = 1.0
    chromaticity: float = 0.5
    real: float = 0.0


def synthetic_loss(
    pred: dict[str, torch.Tensor], target: dict[str, torch.Tensor], valid: torch.Tensor, weights: LossWeights
) -> tuple[torch.Tensor, dict[str, float]]:
    """Masked L2 losses plus chromaticity.

    Args:
        pred: ``normal (B, 3, P)``, ``albedo (B, 3, P)``, ``roughness (B, 1, P)``, ``metallic
            (B, 1, P)`` at P pixels (sampled or all).
        target: the same keys and shapes.
        valid: ``(B, 1, P)`` 0/1 weights of the pixels.
        weights: term weights.

    Returns:
        ``(loss, parts)``: the scalar loss and the value of each active term.
    """
    denom = valid.sum().clamp_min(1.0)
    total = pred["normal"].new_zeros(())
    parts: dict[str, float] = {}
    for key in ("normal", "albedo", "roughness", "metallic"):
        w = getattr(weights, key)
        if w == 0.0:
            continue
        term = (((pred[key] - target[key]) ** 2).sum(dim=1, keepdim=True) * valid).sum() / denom
        total = total + w * term
        parts[key] = float(term.detach())
    if weights.chromaticity != 0.0:
        cos = torch.nn.functional.cosine_similarity(pred["albedo"], target["albedo"], dim=1, eps=1e-6)[:, None]
        term = ((1.0 - cos) * valid).sum() / denom
        total = total + weights.chromaticity * term
        parts["chromaticity"] = float(term.detach())
    return total, parts


def real_loss(
    pred: dict[str, torch.Tensor],
    batch: dict[str, torch.Tensor],
    pixels: torch.Tensor,
    valid: torch.Tensor,
    *,
    floor: float = REAL_FLOOR,
) -> tuple[torch.Tensor, dict[str, float]]:
    r"""Scale-invariant re-rendering error on a real batch (unweighted; the caller applies ``LossWeights.real``).

    At the sampled pixels the predicted maps are re-rendered into unpol ``r_u`` and LP ``r_l``
    (:func:`network.rerender.rerender`) and compared with the observed ``o_u``, ``o_l`` (the
    normalised maps' channels 0-2 and 3-5). Exposure, display brightness and the normalisation
    leave one unknown scale per image, so each image gets the closed-form weighted least-squares
    scale, shared by both maps and all colours (so the diffuse/specular balance and the colour
    stay constrained):

    .. math::
        s^* = \frac{\sum_m w_m \langle o_m, r_m \rangle}{\sum_m w_m \lVert r_m \rVert^2},\quad
        L = \frac{\sum_m w_m \lVert o_m - s^* r_m \rVert^2}{\sum_m w_m \lVert o_m \rVert^2},\quad
        w_m = \frac{1}{\lVert o_m \rVert^2 + f\,(\lVert o_u \rVert^2 + \lVert o_l \rVert^2) / 2}

    over the valid pixels and colours, ``m`` in {unpol, LP}. The weights balance the two maps
    whatever their brightness ratio (a matte object has almost no LP, a metal almost no unpol);
    the floor ``f`` keeps a nearly empty map from amplifying its noise. ``L`` is in [0, 1] (0 =
    perfect up to scale, 1 = nothing explained) and averaged over the images that have valid
    pixels. ``s*`` is not detached: as ``L``'s numerator is minimal in ``s`` at ``s*`` and its
    denominator does not depend on the prediction, the gradient equals the one with ``s*``
    detached (envelope theorem); a re-rendering that is 0 everywhere gets ``s* = 0``, ``L = 1``
    and no gradient. Computed in float32 outside autocast.

    Args:
        pred: ``normal (B, 3, P)``, ``albedo (B, 3, P)``, ``roughness (B, 1, P)``, ``metallic
            (B, 1, P)`` at the sampled pixels.
        batch: a :class:`network.realdata.RealDataset` batch: ``maps (B, 9, H, W)``, ``mask (B, 1,
            H, W)``, ``points (B, 3, H, W)``, ``patches (B, N, 11)``.
        pixels: ``(B, P)`` flat pixel indices of ``pred``.
        valid: ``(B, 1, P)`` 0/1 weights of the pixels.
        floor: ``f`` above.

    Returns:
        ``(loss, parts)``: the scalar loss and ``{"real": loss, "real_scale": mean s*}``.
    """
    device_type = pred["normal"].device.type
    with torch.autocast(device_type=device_type, enabled=False):
        f32 = {k: pred[k].float() for k in ("normal", "albedo", "roughness", "metallic")}
        points = gather_pixels(batch["points"].float(), pixels)
        obs = gather_pixels(batch["maps"][:, :6].float(), pixels)
        w = valid.float() * gather_pixels(batch["mask"].float(), pixels)
        ren = rerender(**f32, points=points, patches=Patches.unpack(batch["patches"].float()))
        o = (obs * w).unflatten(1, (2, 3))  # (B, map, colour, P)
        r = (torch.cat([ren["unpol"], ren["lp"]], 1) * w).unflatten(1, (2, 3))
        energy = (o * o).sum((2, 3))  # (B, 2)
        wm = 1.0 / (energy + floor * energy.mean(1, keepdim=True)).clamp_min(1e-20)
        num = (wm * (o * r).sum((2, 3))).sum(1)
        den = (wm * (r * r).sum((2, 3))).sum(1)
        scale = num / den.clamp_min(1e-20)
        resid = (wm * ((o - scale[:, None, None, None] * r) ** 2).sum((2, 3))).sum(1)
        total = (wm * energy).sum(1)
        has = (w.flatten(1).sum(1) > 0) & (total > 0)
        per_image = torch.where(has, resid / total.clamp_min(1e-20), torch.zeros_like(resid))
        loss = per_image.sum() / has.sum().clamp_min(1)
    scale_mean = float(scale[has].mean().detach()) if bool(has.any()) else 0.0
    return loss, {"real": float(loss.detach()), "real_scale": scale_mean}
