"""Does the re-renderer's material model explain this object? The guard of the test-time refinement.

Issue 27, item 2. The refinement (:mod:`network.refine`, :mod:`network.refine_roughness`) trusts the
re-renderer's ``pplastic``-like model: a Fresnel-weighted Lambert diffuse in unpol and a GGX lobe
with IOR 1.5 in LP. Where the capture is something else (an expanded measured pBRDF table, whose LP
is ~40 % below that lobe and whose unpol is ~20 % above it; a metal taken for a dielectric; cast
shadows and interreflections) the fitted scale or roughness is wrong, with a small residual. The
cue that needs no ground truth is the **LP gain**: the decoded LP over the LP the re-renderer
predicts from the network's maps (normals, roughness) at the display's known radiance, summed over
the object's confident pixels. The albedo does not enter the LP of a dielectric, so the gain tests
the material model independently of the scale being fitted. An object whose gain is below
:attr:`GuardParams.albedo_lp_gain` keeps the network's albedo; below :attr:`GuardParams.lp_gain` (a
stricter floor: the roughness is read from the lobe's shape) its roughness. The albedo has a second
guard, the scale itself: a fit that darkens the network's albedo below :attr:`GuardParams.scale`'s
lower end is not applied (on validation, such fits were cast shadows, occluded display light and
metals more often than albedos that wrong).

The thresholds were chosen on validation splits only (docs/measurements/refine.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GUARD", "OFF", "GuardParams", "lp_gain", "lp_untrusted", "scale_untrusted"]


@dataclass(frozen=True)
class GuardParams:
    """Thresholds of the guard (chosen on validation splits only: docs/measurements/refine.md).

    Attributes:
        scale: ``(low, high)``: a fitted albedo scale outside it is not applied (the object keeps the
            network's albedo). Below ``low`` the fit more likely met what darkens a capture against the
            re-rendering (a cast shadow, the display occluded by another object, a metal taken for a
            dielectric) than an albedo that bright.
        albedo_lp_gain: ``(low, high)``: an object whose LP gain (:func:`lp_gain`) is outside it keeps the
            network's albedo (almost no or negative LP where the re-renderer predicts a lobe: a measured
            material's own polarization, a metal, a shadowed object).
        lp_gain: ``(low, high)``: an object whose LP gain is outside it keeps the network's roughness (its
            LP lobe is not the re-renderer's GGX lobe).
        shrink: the applied scale is ``s ** shrink`` (1: the fit; below 1 towards the network's albedo, the
            MAP of a log-normal prior around it when the fit's loss is quadratic in ``log s``).
        min_lp: the re-rendered LP must carry at least this share of the re-rendered unpol over the
            object (a faint lobe cannot tell the gain; the guard then does not judge).
    """

    scale: tuple[float, float] = (0.6, 4.0)
    albedo_lp_gain: tuple[float, float] = (0.2, 1.5)
    lp_gain: tuple[float, float] = (0.45, float("inf"))
    shrink: float = 0.5
    min_lp: float = 0.0


#: The guard the refinement applies.
GUARD = GuardParams()
#: No guard (for measuring what it does; the scale search's own range still applies).
OFF = GuardParams((0.0, float("inf")), (-float("inf"), float("inf")), (-float("inf"), float("inf")), shrink=1.0)


def lp_gain(obs_lp: np.ndarray, model_lp: np.ndarray, weight: np.ndarray) -> float:
    """Decoded LP over re-rendered LP, ratio of the weighted totals (nan without re-rendered signal).

    A ratio of totals, not a least-squares gain: a lobe shifted by a normal error keeps its total
    but not its overlap with the decoded one.

    Args:
        obs_lp: ``(P, 3)`` decoded LP in the display's radiance units.
        model_lp: ``(P, 3)`` re-rendered LP from the network's maps.
        weight: ``(P,)`` pixel weights >= 0.

    Returns:
        The gain (1 where the model explains the LP's level).

    Example:
        >>> m = np.full((10, 3), 0.1)
        >>> round(lp_gain(0.6 * m, m, np.ones(10)), 3)
        0.6
    """
    den = float(np.sum(weight[:, None] * np.nan_to_num(model_lp)))
    num = float(np.sum(weight[:, None] * np.nan_to_num(obs_lp)))
    return num / den if den > 1e-30 else float("nan")


def lp_untrusted(
    gain: float, lp_share: float, params: GuardParams = GUARD, window: tuple[float, float] | None = None
) -> str | None:
    """Why an object's LP is not the re-renderer's (the map the window guards is kept), or None.

    Args:
        gain: the object's :func:`lp_gain`.
        lp_share: re-rendered LP over re-rendered unpol, totals over the object.
        params: :class:`GuardParams`.
        window: the accepted gains (default ``params.lp_gain``, the roughness's).

    Returns:
        A reason for the user, or None.
    """
    if not np.isfinite(gain):
        return "no re-rendered LP to compare its LP with"
    if not lp_share >= params.min_lp:
        return None
    low, high = params.lp_gain if window is None else window
    if gain < low:
        return f"its LP is {gain:.2f} of what the re-renderer predicts (a measured or unmodelled material)"
    if gain > high:
        return f"its LP is {gain:.2f} times what the re-renderer predicts (a metal or a glint)"
    return None


def scale_untrusted(scale: float, params: GuardParams = GUARD) -> str | None:
    """Why a fitted albedo scale is not applied, or None.

    Args:
        scale: the object's fitted scale of the network's albedo.
        params: :class:`GuardParams`.

    Returns:
        A reason for the user, or None.
    """
    low, high = params.scale
    if not low <= scale <= high:
        return (
            f"its fitted albedo scale {scale:.2f} is outside [{low}, {high}] (a shadow, an occluded display or a metal)"
        )
    return None
