"""Pretrained ViT weights for the tokenizer, read from a local state-dict file.

The file is a ``torch.save`` of a flat ``{name: tensor}`` dict with :class:`~network.model.tokenizer.ViTTokenizer`
key names, which are DINOv2's own (e.g. a ``dinov2_vits14_reg4`` checkpoint, or ``model.tokenizer.state_dict()``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import Tensor

from .polar_model import PolarInverseModel
from .tokenizer import IN_CHANS, ViTTokenizer, interpolate_pos_embed

__all__ = ["IGNORED_PRETRAINED_KEYS", "LoadReport", "load_pretrained_vit"]

#: Keys of DINOv2 checkpoints that the tokenizer does not use (ignored, reported).
IGNORED_PRETRAINED_KEYS = ("mask_token",)


@dataclass
class LoadReport:
    """What :func:`load_pretrained_vit` did.

    Attributes:
        loaded: Keys copied into the tokenizer.
        adapted: Keys copied after a documented conversion (position-grid resize, RGB -> (value, mask) channels).
        missing: Tokenizer keys absent from the file (left as initialised).
        unexpected: File keys the tokenizer does not have.
        mismatched: ``(key, expected shape, file shape)`` that could not be converted.
        ignored: Known unused DINOv2 keys (``mask_token``).
    """

    loaded: list[str] = field(default_factory=list)
    adapted: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    unexpected: list[str] = field(default_factory=list)
    mismatched: list[tuple[str, tuple[int, ...], tuple[int, ...]]] = field(default_factory=list)
    ignored: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """True when every tokenizer key was loaded and nothing was left over."""
        return not (self.missing or self.unexpected or self.mismatched)

    def summary(self, limit: int = 10) -> str:
        """One line per problem category, each listing at most ``limit`` keys."""

        def show(items: list) -> str:
            more = f" ... (+{len(items) - limit} more)" if len(items) > limit else ""
            return ", ".join(str(i) for i in items[:limit]) + more

        lines = [f"loaded {len(self.loaded)} tensors ({len(self.adapted)} adapted)"]
        if self.missing:
            lines.append(f"missing {len(self.missing)}: {show(self.missing)}")
        if self.unexpected:
            lines.append(f"unexpected {len(self.unexpected)}: {show(self.unexpected)}")
        if self.mismatched:
            lines.append(f"shape mismatch {len(self.mismatched)} (key, expected, file): {show(self.mismatched)}")
        return "; ".join(lines)


def load_pretrained_vit(
    model: PolarInverseModel | ViTTokenizer, path: str | Path, *, strict: bool = True
) -> LoadReport:
    """Load tokenizer weights from a local file.

    Format: ``torch.save`` of a flat dict ``{name: tensor}`` with the :class:`ViTTokenizer` key names (DINOv2's
    own; e.g. ``model.tokenizer.state_dict()``, or a DINOv2-reg checkpoint such as ``dinov2_vits14_reg4``). It is
    read with ``torch.load(weights_only=True)``, so no code is unpickled. Conversions applied:

    - ``pos_embed`` with another square grid: resized bicubically to the tokenizer's grid.
    - ``patch_embed.proj.weight`` with 3 input channels (RGB, as DINOv2): summed into the value channel (a
      grey map replicated to RGB gives the same response), zeros for the mask channel.
    - ``mask_token`` is ignored.

    A different patch size or width cannot be converted and is reported as a shape mismatch.

    Args:
        model: A :class:`PolarInverseModel` (its ``tokenizer`` is loaded) or a :class:`ViTTokenizer`.
        path: The file.
        strict: Raise unless every tokenizer key loads and no file key is left over. With ``strict=False``,
            loadable tensors are copied and the rest reported.

    Returns:
        A :class:`LoadReport`.

    Raises:
        OSError: If the file cannot be read.
        ValueError: If the file is not a dict of tensors, or (strict) on missing, unexpected or mismatched keys;
            the message names the file and the keys. Nothing is copied in that case.
    """
    tokenizer = model.tokenizer if isinstance(model, PolarInverseModel) else model
    path = Path(path)
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError) as exc:
        raise OSError(f"Cannot read pretrained ViT weights from {path}: {exc}") from exc
    if not isinstance(state, dict) or not all(isinstance(v, Tensor) for v in state.values()):
        raise ValueError(f"{path}: expected a flat dict of tensors (a state dict), got {type(state).__name__}")
    own = tokenizer.state_dict()
    report = LoadReport()
    converted: dict[str, Tensor] = {}
    for key, value in state.items():
        if key in IGNORED_PRETRAINED_KEYS:
            report.ignored.append(key)
            continue
        if key not in own:
            report.unexpected.append(key)
            continue
        target = own[key]
        if value.shape == target.shape:
            converted[key] = value
            report.loaded.append(key)
            continue
        adapted = _adapt_pretrained(key, value, target, tokenizer)
        if adapted is None:
            report.mismatched.append((key, tuple(target.shape), tuple(value.shape)))
        else:
            converted[key] = adapted
            report.loaded.append(key)
            report.adapted.append(key)
    report.missing = [k for k in own if k not in state]
    if strict and not report.ok:
        raise ValueError(f"{path}: pretrained ViT weights do not match the tokenizer: {report.summary()}")
    with torch.no_grad():
        for key, value in converted.items():
            own[key].copy_(value.to(own[key].dtype))
    return report


def _adapt_pretrained(key: str, value: Tensor, target: Tensor, tokenizer: ViTTokenizer) -> Tensor | None:
    """Convert a pretrained tensor of another shape, or None when no documented conversion applies."""
    if key == "pos_embed" and value.ndim == 3 and value.shape[2] == target.shape[2]:
        side = math.isqrt(target.shape[1] - 1)
        try:
            return interpolate_pos_embed(value, (side, side))
        except ValueError:
            return None
    if (
        key == "patch_embed.proj.weight"
        and value.ndim == 4
        and value.shape[1] == 3
        and target.shape[1] == IN_CHANS
        and (value.shape[0], value.shape[2], value.shape[3]) == (target.shape[0], target.shape[2], target.shape[3])
    ):
        out = torch.zeros_like(target, dtype=value.dtype)
        out[:, 0] = value.sum(dim=1)
        return out
    return None
