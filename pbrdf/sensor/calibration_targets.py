"""Synthetic captures of the calibration targets from a rig with known imperfections.

The targets of :mod:`pbrdf.sensor.calibration` are simple enough for closed-form Stokes images:

* ``dark``: nothing but the ambient light the camera model adds;
* ``white``: a Lambertian plane facing the camera, ``s0 = albedo / pi E`` of one display primary at
  a commanded level (:func:`pbrdf.sensor.calibration_display.white_radiance`: the display's emission
  profile and tone response included), unpolarized;
* ``polarizer``: the display seen directly through an ideal linear polarizer at ``phi``: the
  display's Stokes ``L (1, DoP cos 2 psi, DoP sin 2 psi, 0)`` times the polarizer's Mueller matrix
  (:func:`pbrdf.polar.mueller.linear_polarizer`), the same in every colour region and, with the
  camera facing the display, falling across the frame with the emission profile ``cos^p`` of the
  pixel ray's angle to the optical axis.

Each is passed through the project's forward model (:func:`pbrdf.sensor.camera.simulate_capture`:
cross-talk, ambient, vignetting, QWP, analyzers, mosaic, Poisson-Gaussian noise, HDR bracket)
with the true camera model, and given dark frames of its own (the same bracket with zero Stokes).
The :class:`~pbrdf.sensor.calibration.Target` records what a lab knows: the geometry, the sensor
and the bracket, but the nominal imperfection fields.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from pbrdf.polar import mueller
from pbrdf.sensor.calibration import CHANNELS, Target
from pbrdf.sensor.calibration_display import white_radiance
from pbrdf.sensor.camera import CameraModel, simulate_capture
from pbrdf.sensor.display_response import emission_profile
from pbrdf.sensor.projection import pinhole_intrinsics, pixel_rays
from pbrdf.sensor.rig import Rig

__all__ = ["DEFAULT_ANGLES_DEG", "DEFAULT_LEVELS", "SECOND_DISTANCE_M", "target_stokes", "lab_rig", "simulate_targets"]

#: Polarizer angles (degrees, analyzer frame) of the synthetic polarizer targets.
DEFAULT_ANGLES_DEG = (0.0, 30.0, 60.0, 90.0, 120.0, 150.0)
#: Commanded levels below full of the synthetic white targets (the tone response), per primary.
DEFAULT_LEVELS = (0.25, 0.5)
#: Second distance (m) of the synthetic white targets at full level (the emission profile).
SECOND_DISTANCE_M = 0.4


def target_stokes(
    kind: str,
    rig: Rig,
    shape: tuple[int, int],
    *,
    display_channel: int | None = None,
    polarizer_angle: float | None = None,
    distance_m: float = 0.7,
    albedo: float = 0.99,
    intrinsics: NDArray | None = None,
    level: float = 1.0,
) -> NDArray[np.float64]:
    """Stokes images ``(H, W, 3, 4)`` (colour axis = display region) of one calibration target.

    Args:
        kind: ``"dark"``, ``"white"`` or ``"polarizer"``.
        rig: the true rig (display geometry, radiance, DoP and angle).
        shape: ``(H, W)`` raw frame.
        display_channel: ``white``: the primary shown (0, 1, 2).
        polarizer_angle: ``polarizer``: transmission axis in radians (analyzer frame).
        distance_m: ``white``: the plane's distance in m.
        albedo: ``white``: the Lambertian reflectance.
        intrinsics: ``K (3, 3)`` of the raw grid; None: the rig camera's focal length, centred.
        level: ``white``: the commanded level of the primary.

    Returns:
        ``(H, W, 3, 4)`` float64.
    """
    h, w = shape
    out = np.zeros((h, w, 3, 4))
    if kind == "dark":
        return out
    rays = pixel_rays(pinhole_intrinsics(rig.camera.focal_length_px, w, h) if intrinsics is None else intrinsics, h, w)
    if kind == "white":
        radiance = white_radiance(rig, rays, distance_m, albedo, channel=display_channel, level=level)
        out[:, :, display_channel, 0] = radiance
        return out
    if kind == "polarizer":
        d = rig.display
        psi, dop, radiance = d.polarization_angle, d.degree_of_polarization, d.radiance
        emitted = radiance * np.array([1.0, dop * np.cos(2 * psi), dop * np.sin(2 * psi), 0.0])
        out[...] = mueller.linear_polarizer(polarizer_angle) @ emitted
        if d.emission_exponent:  # the camera faces the display: each pixel sees it along its own ray
            out *= emission_profile(1.0 / np.linalg.norm(rays, axis=-1), d.emission_exponent)[..., None, None]
        return out
    raise ValueError(f"kind must be 'dark', 'white' or 'polarizer'; got {kind!r}")


def lab_rig(rig: Rig) -> Rig:
    """What the lab assumes: the rig's geometry, sensor and bracket with nominal imperfection fields."""
    m = rig.camera.model
    nominal = CameraModel(
        analyzer_transmittance=m.analyzer_transmittance,
        exposures=m.exposures,
        sensor=m.sensor,
        pattern_offset=m.pattern_offset,
    )
    display = dataclasses.replace(
        rig.display, degree_of_polarization=1.0, polarization_angle=np.pi / 2, emission_exponent=0.0, tone_gamma=1.0
    )
    return Rig(display, dataclasses.replace(rig.camera, model=nominal))


def simulate_targets(
    rig: Rig,
    shape: tuple[int, int],
    *,
    rng: np.random.Generator | None = None,
    noise: bool = True,
    distance_m: float = 0.7,
    albedo: float = 0.99,
    angles_deg: tuple[float, ...] = DEFAULT_ANGLES_DEG,
    intrinsics: NDArray | None = None,
    second_distance_m: float | None = SECOND_DISTANCE_M,
    levels: tuple[float, ...] = DEFAULT_LEVELS,
) -> list[Target]:
    """The full target set (one dark, three white, the polarizer angles) from a rig with known imperfections.

    Args:
        rig: the true rig (``rig.camera.model`` with its imperfections, the display's DoP and angle).
        shape: ``(H, W)`` raw frame, multiples of 4.
        rng: random generator (required with ``noise``).
        noise: Poisson-Gaussian noise on.
        distance_m: white target distance in m.
        albedo: white target reflectance.
        angles_deg: polarizer angles in degrees.
        intrinsics: ``K (3, 3)`` of the raw grid; None: the rig camera's focal length, centred.
        second_distance_m: the white targets again at full level at this distance (the emission
            profile); None: not captured.
        levels: commanded levels below 1 at which each primary is captured again at ``distance_m``
            (the tone response); empty: none.

    Returns:
        The targets, each with dark frames of its own (the dark target's are its raws' own).
    """
    model = rig.camera.model
    lab = lab_rig(rig)
    k = None if intrinsics is None else np.asarray(intrinsics, dtype=np.float64)

    def shot(stokes: NDArray) -> NDArray:
        return simulate_capture(stokes, model, rng=rng, noise=noise)

    zeros = target_stokes("dark", rig, shape)
    common = {"model": lab.camera.model, "rig": lab, "intrinsics": k}
    targets = [Target(name="dark", kind="dark", raws=shot(zeros), **common)]
    whites = [("", distance_m, 1.0)] + [(f"_{round(100 * v):03d}", distance_m, v) for v in levels]
    if second_distance_m is not None:
        whites.append(("_second", second_distance_m, 1.0))
    for suffix, dist, level in whites:
        for c in range(3):
            s = target_stokes("white", rig, shape, display_channel=c, distance_m=dist, albedo=albedo, intrinsics=k,
                              level=level)  # fmt: skip
            targets.append(Target(name=f"white_{CHANNELS[c].lower()}{suffix}", kind="white", raws=shot(s),
                                  dark=shot(zeros), display_channel=c, albedo=albedo, distance_m=dist, level=level,
                                  **common))  # fmt: skip
    for deg in angles_deg:
        s = target_stokes("polarizer", rig, shape, polarizer_angle=np.deg2rad(deg))
        targets.append(Target(name=f"polarizer_{deg:05.1f}", kind="polarizer", raws=shot(s), dark=shot(zeros),
                              polarizer_angle=float(np.deg2rad(deg)), **common))  # fmt: skip
    return targets
