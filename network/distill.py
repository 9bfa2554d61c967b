"""Fine-tuning without forgetting: a frozen teacher's maps as an extra target (learning without forgetting).

A model fine-tuned for a new input (the light input) on new data can lose what it did well before:
the lighting-aware fine-tunes of ``small`` lost metallic accuracy on the light-blind model's own test
splits (docs/measurements/light_model.md). :class:`Teacher` is a frozen checkpoint (typically the
model being fine-tuned, as shipped) run on the same batch and pixels as the student; :func:`distill_loss`
is the masked L2 between the student's and the teacher's maps for the chosen keys, added to the
training loss with its own weight (``headless/train.py --distill-from CKPT --distill-weight W
--distill-keys metallic``). The teacher sees the maps it was trained on (its own input variant and
scale must be the run's) and the light vectors only if it was trained with them.

Example:
    >>> import torch
    >>> p = {"metallic": torch.tensor([[[0.2, 0.4]]])}
    >>> t = {"metallic": torch.tensor([[[0.0, 0.4]]])}
    >>> round(float(distill_loss(p, t, torch.ones(1, 1, 2), ("metallic",))), 4)
    0.02
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch
from torch import Tensor

from .checkpoint import load_checkpoint, require_trained_with
from .data import TARGET_KEYS
from .inputs import apply_inputs

__all__ = ["Teacher", "check_distill", "distill_loss"]


def check_distill(source: Path | None, weight: float, keys: Sequence[str]) -> None:
    """ValueError unless the distillation settings are usable (a weight > 0 needs a teacher, keys are map names)."""
    if not (weight >= 0 and weight < float("inf")):
        raise ValueError(f"distill_weight must be a finite number >= 0. Got {weight!r}")
    if weight > 0 and source is None:
        raise ValueError("distill_weight > 0 needs distill_from (the teacher checkpoint)")
    bad = [k for k in keys if k not in TARGET_KEYS]
    if bad or not keys:
        raise ValueError(f"distill_keys must be a non-empty subset of {TARGET_KEYS}. Got {tuple(keys)!r}")


def distill_loss(pred: dict[str, Tensor], teacher: dict[str, Tensor], valid: Tensor, keys: Sequence[str]) -> Tensor:
    """Masked L2 between the student's and the teacher's maps, summed over ``keys`` and their channels.

    Args:
        pred: the student's maps, e.g. ``metallic (B, 1, P)`` at P pixels.
        teacher: the teacher's maps at the same pixels (no gradient flows into them).
        valid: ``(B, 1, P)`` 0/1 weights of the pixels.
        keys: the maps distilled.

    Returns:
        The scalar loss (mean over valid pixels; 0 when no pixel is valid).
    """
    denom = valid.sum().clamp_min(1.0)
    total = valid.new_zeros(())
    for k in keys:
        total = total + (((pred[k] - teacher[k].detach()) ** 2).sum(dim=1, keepdim=True) * valid).sum() / denom
    return total


class Teacher:
    """A frozen checkpoint predicting at the student's training pixels.

    Args:
        path: the teacher's ``model.pt``.
        inputs, input_scale: the run's input variant and scale; the teacher must have been trained with both.
        device: where it runs.
        bf16: run under bf16 autocast (as the student does with ``bf16``).

    Raises:
        ValueError: the checkpoint is unreadable or was trained with another input variant or scale.
    """

    def __init__(
        self, path: str | Path, inputs: str, input_scale: str, device: torch.device, bf16: bool = False
    ) -> None:
        self.model, ckpt = load_checkpoint(path)
        require_trained_with(ckpt, path, "distill_from", inputs, input_scale)
        self.model = self.model.to(device).eval().requires_grad_(False)
        self.inputs = inputs
        self.light_input = bool(self.model.config.light_input)
        self.device, self.bf16 = device, bf16

    @torch.no_grad()
    def __call__(self, maps: Tensor, mask: Tensor, pixels: Tensor, valid: Tensor, light: Tensor | None) -> dict:
        """The teacher's maps (float32) at ``pixels`` (B, P) of a batch's measured ``maps`` (B, 9, H, W)."""
        x = apply_inputs(maps, self.inputs)
        lt = light if self.light_input else None
        with torch.autocast(device_type=self.device.type, dtype=torch.bfloat16, enabled=self.bf16):
            pred = self.model.decode_pixels(self.model.encode(x, mask.to(x.dtype), lt), x, pixels, valid, lt)
        return {k: v.float() for k, v in pred.items()}
