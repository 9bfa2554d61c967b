"""Input variants of the ablation (Table 3 of the paper): which of the nine maps the network sees.

The network always takes nine maps in :data:`pbrdf.sensor.decode.NINE_MAP_NAMES` order
``[R,G,B unpol, R,G,B LP, R,G,B CP]``; a variant zeroes what its capture setup could not measure:

``"white"``
    Uniform white illumination, intensity only: a plain camera under a display showing white
    everywhere. Same maps as ``"spectral"`` (S0 per colour in the unpol slots, LP and CP zero);
    the difference is in the DATA, which must be rendered with the rig's built-in ``white``
    pattern, e.g. ``headless/render.py --rig white.json`` with ``white.json`` =
    ``{"display": {"pattern": "white"}}`` (a partial rig override, see
    :meth:`pbrdf.sensor.rig.Rig.from_dict`).
``"spectral"``
    + spectral multiplexing: the RGB display pattern (``rgb_halves``), intensity only. Each
    colour's total intensity ``S0 = unpol + LP`` goes into its unpol slot; LP and CP are zero.
``"polar"``
    + polarization decomposition: unpol and LP maps, CP zero (no quarter-wave plate).
``"full"``
    + circular polarization: all nine maps (the paper's method).

:func:`apply_inputs` keeps ``unpol + LP`` per colour unchanged, so it commutes with
:func:`network.data.normalize_maps` (whose scale is a quantile of that sum): applying it to raw
or to normalised maps gives the same network input. Checkpoints store their variant under the
key ``"inputs"``; :func:`checkpoint_inputs` reads it (``"full"`` when absent).
"""

from __future__ import annotations

from collections.abc import Mapping

import torch

__all__ = ["INPUT_VARIANTS", "apply_inputs", "checkpoint_inputs"]

INPUT_VARIANTS = ("white", "spectral", "polar", "full")


def apply_inputs(maps: torch.Tensor, variant: str) -> torch.Tensor:
    """Zero the maps a variant does not measure.

    Args:
        maps: ``(..., 9, H, W)`` nine maps (raw or normalised).
        variant: one of :data:`INPUT_VARIANTS`.

    Returns:
        ``(..., 9, H, W)`` a new tensor (``maps`` itself for ``"full"``).

    Raises:
        ValueError: On an unknown variant or a shape other than ``(..., 9, H, W)``.

    Example:
        >>> maps = torch.arange(1.0, 10.0).reshape(9, 1, 1)  # one pixel: unpol 1-3, LP 4-6, CP 7-9
        >>> apply_inputs(maps, "polar").flatten().tolist()
        [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 0.0, 0.0, 0.0]
        >>> apply_inputs(maps, "spectral").flatten().tolist()  # S0 = unpol + LP per colour
        [5.0, 7.0, 9.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    """
    if variant not in INPUT_VARIANTS:
        raise ValueError(f"unknown input variant {variant!r}; choose one of {INPUT_VARIANTS}")
    if maps.ndim < 3 or maps.shape[-3] != 9:
        raise ValueError(f"expected maps (..., 9, H, W), got {tuple(maps.shape)}")
    if variant == "full":
        return maps
    unpol, lp, cp = maps[..., 0:3, :, :], maps[..., 3:6, :, :], maps[..., 6:9, :, :]
    if variant == "polar":
        return torch.cat([unpol, lp, torch.zeros_like(cp)], dim=-3)
    return torch.cat([unpol + lp, torch.zeros_like(lp), torch.zeros_like(cp)], dim=-3)  # intensity S0 only


def checkpoint_inputs(ckpt: Mapping) -> str:
    """The input variant a checkpoint was trained with (``"full"`` when it does not say)."""
    variant = ckpt.get("inputs", "full")
    if variant not in INPUT_VARIANTS:
        raise ValueError(f"checkpoint has unknown input variant {variant!r}; expected one of {INPUT_VARIANTS}")
    return variant
