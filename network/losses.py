"""Training losses on the synthetic data (masked), with zero-weight terms skipped.

``L = w_n |n - n*|^2 + w_a |a - a*|^2 + w_r (r - r*)^2 + w_m (m - m*)^2 + w_c (1 - cos(a, a*))``
averaged over valid pixels; the last term is the albedo chromaticity loss (the angle between
predicted and true RGB albedo vectors, insensitive to the global scale that the display's
brightness cannot fix).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

__all__ = ["LossWeights", "synthetic_loss"]


@dataclass(frozen=True)
class LossWeights:
    """Weights of the loss terms; a 0 weight skips the term entirely (no compute)."""

    normal: float = 1.0
    albedo: float = 1.0
    roughness: float = 1.0
    metallic: float = 1.0
    chromaticity: float = 0.5


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
