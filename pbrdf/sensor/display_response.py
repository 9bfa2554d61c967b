"""The display's angular emission profile and tone response: the one home of both laws and their checks.

Emission profile. An LCD's radiance falls with the emission angle ``theta`` (from the panel's front
normal): the liquid-crystal cell and the polarizer films transmit less off axis. The model is

.. math:: L(\\theta) = L_0 \\cos^p \\theta

with ``L_0`` the radiance along the normal (``display.radiance`` times the pattern level) and ``p`` =
``display.emission_exponent``. ``p = 0`` is the flat (Lambertian) emitter every renderer and closed
form used before; ``p = 1`` halves the radiance at 60 degrees, ``p = 2`` at 45.

Tone response. The level the display emits for a commanded pattern value ``v`` in ``[0, 1]`` is
``v ** gamma_c`` per colour channel (``display.tone_gamma``), relative to the full-on level: 0 and 1
are fixed points, so the built-in binary patterns are unaffected and the response matters only for
image patterns and calibration targets at intermediate levels. Nominal ``gamma = 1``: the pattern
values are linear radiance, as before.

Ranges (:data:`PROFILE_RANGES`): checked by :class:`~pbrdf.sensor.rig.DisplaySpec` through
:func:`check_emission_exponent` and :func:`check_tone_gamma`; physical meaning and the drawn
residuals: docs/rig_imperfections.md.

Example:
    >>> round(float(emission_profile(0.5, 1.0)), 3), float(emission_profile(0.5, 0.0))
    (0.5, 1.0)
    >>> tone_response(np.array([[0.0, 0.5, 1.0]]), (1.0, 2.0, 1.0)).tolist()
    [[0.0, 0.25, 1.0]]
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "PROFILE_RANGES",
    "NOMINAL_GAMMA",
    "check_emission_exponent",
    "check_tone_gamma",
    "emission_profile",
    "tone_response",
]

#: Valid ranges ``(low, high)``, both inclusive: ``emission_exponent`` (0 = flat; 8 halves the radiance
#: at 34 degrees, far beyond a real panel) and each channel's ``tone_gamma`` (0.2 - 5 spans linear,
#: sRGB-like 2.2 and the inverse of either).
PROFILE_RANGES = {"emission_exponent": (0.0, 8.0), "tone_gamma": (0.2, 5.0)}
#: The nominal tone response: the commanded level is the emitted one.
NOMINAL_GAMMA = (1.0, 1.0, 1.0)


def _number(value: Any, name: str, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ValueError(f"{name} must be a number in [{lo:g}, {hi:g}]; got {str(value)[:40]!r}")
    x = float(value)
    if not lo <= x <= hi:  # also refuses NaN and inf
        raise ValueError(f"{name} must be in [{lo:g}, {hi:g}]; got {x:g}")
    return x


def check_emission_exponent(value: Any) -> float:
    """``value`` as the exponent ``p`` of ``cos^p``; ValueError naming ``display.emission_exponent`` otherwise."""
    return _number(value, "display.emission_exponent", *PROFILE_RANGES["emission_exponent"])


def check_tone_gamma(value: Any) -> tuple[float, float, float]:
    """``value`` (one number or three, R, G, B) as three gammas; ValueError naming ``display.tone_gamma`` otherwise.

    >>> check_tone_gamma(2.2), check_tone_gamma([1, 1.1, 0.9])
    ((2.2, 2.2, 2.2), (1.0, 1.1, 0.9))
    """
    values = list(value) if isinstance(value, list | tuple | np.ndarray) else [value]
    if len(values) == 1:
        values = values * 3
    if len(values) != 3:
        raise ValueError(f"display.tone_gamma must be one number or three (R, G, B); got {len(values)} values")
    lo, hi = PROFILE_RANGES["tone_gamma"]
    return tuple(_number(v, f"display.tone_gamma[{c}]", lo, hi) for c, v in zip("RGB", values, strict=True))  # type: ignore[return-value]


def emission_profile(cos_theta: ArrayLike, exponent: float) -> NDArray[np.float64]:
    """Relative radiance ``cos^p theta`` (0 behind the panel, 1 for ``p = 0`` in front of it).

    Args:
        cos_theta: ``(...)`` cosine of the emission angle from the front normal.
        exponent: ``p`` (:func:`check_emission_exponent`).

    Returns:
        ``(...)`` float64 in ``[0, 1]``, finite for any finite input.
    """
    c = np.clip(np.asarray(cos_theta, dtype=np.float64), 0.0, 1.0)
    if exponent == 0.0:
        return (c > 0).astype(np.float64)
    return c**exponent


def tone_response(levels: ArrayLike, gamma: tuple[float, float, float]) -> NDArray:
    """Emitted relative levels ``(..., 3)`` of commanded levels ``(..., 3)`` in ``[0, 1]``: ``v ** gamma_c``.

    The nominal gamma returns the input itself (bit-identical); levels are clipped to ``[0, 1]``.
    The dtype of a floating input is kept.
    """
    v = np.asarray(levels)
    if tuple(gamma) == NOMINAL_GAMMA:
        return v
    dtype = v.dtype if np.issubdtype(v.dtype, np.floating) else np.float64
    return (np.clip(v, 0.0, 1.0) ** np.asarray(gamma, dtype=np.float64)).astype(dtype)
