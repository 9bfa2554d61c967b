"""Display-camera measurement model: QWP, micro-polarizer analyzers, IMX250MYR mosaic, noise, brackets.

The forward chain for one frame is

    Stokes images per colour (H, W, 3, 4)
      -> quarter-wave plate (fast axis ``qwp_angle``, retardance per colour channel)
      -> the pixel's analyzer (0/45/90/135 degrees, extinction ratio per colour channel)
      -> IMX250MYR 4x4 colour-polarization mosaic (H, W)
      -> photo-electrons for an exposure time, Poisson-Gaussian noise, full well
      -> gain, black level, 12-bit quantisation and clipping -> uint16 raw.

:mod:`pbrdf.sensor.decode` inverts it with the same :class:`CameraModel`, for synthetic and real captures.

Convention (IMX250MYR layout, row 0 at the top of the image, ``pattern_offset = (0, 0)``):

=====  =====  =====  =====  =====
 row   col 0  col 1  col 2  col 3
=====  =====  =====  =====  =====
  0    R90    R45    G90    G45
  1    R135   R0     G135   G0
  2    G90    G45    B90    B45
  3    G135   G0     B135   B0
=====  =====  =====  =====  =====

Each 2x2 block shares one colour (RGGB Bayer over blocks) and holds the four analyzer angles as
``[[90, 45], [135, 0]]``. A sensor ROI that starts at an odd row or column shifts this table;
``pattern_offset`` says where pixel (0, 0) of the raw falls in it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf.polar import mueller

__all__ = [
    "ANGLES_DEG",
    "MOSAIC_COLOR",
    "MOSAIC_ANGLE",
    "SensorParams",
    "CameraModel",
    "measurement_matrix",
    "mosaic_indices",
    "analyzer_intensities",
    "mosaic",
    "expose",
    "simulate_capture",
]

#: Analyzer angles in degrees, in the order used for the angle axis everywhere.
ANGLES_DEG = (0, 45, 90, 135)
#: Colour index (0 = R, 1 = G, 2 = B) of each pixel of the 4x4 super-pixel.
MOSAIC_COLOR = np.array([[0, 0, 1, 1], [0, 0, 1, 1], [1, 1, 2, 2], [1, 1, 2, 2]], dtype=np.intp)
#: Analyzer angle index into :data:`ANGLES_DEG` of each pixel of the 4x4 super-pixel.
MOSAIC_ANGLE = np.array([[2, 1, 2, 1], [3, 0, 3, 0], [2, 1, 2, 1], [3, 0, 3, 0]], dtype=np.intp)


@dataclass(frozen=True)
class SensorParams:
    """Linear sensor model (EMVA 1288 style). Defaults: IMX250 family at 12 bit.

    Attributes:
        gain: system gain K in DN per electron (about 0.38 for the IMX250 at 12 bit).
        read_noise: temporal dark noise in electrons (about 2.95 e-).
        full_well: saturation capacity in electrons (about 10.7 ke-).
        black_level: offset added to every pixel, in DN.
        bits: ADC bit depth; the white level is ``2**bits - 1``.
        electrons_per_unit: photo-electrons per second produced by an analyzer intensity of 1 in
            the renderer's linear radiance units (the radiometric calibration of the rig). The
            default makes ``s0 = 1`` fill about 75 % of the well in the shortest bracket.
        saturation: fraction of the white level from which a pixel counts as saturated.
    """

    gain: float = 0.38
    read_noise: float = 2.95
    full_well: float = 10700.0
    black_level: float = 16.0
    bits: int = 12
    electrons_per_unit: float = 8.0e5
    saturation: float = 0.95

    def __post_init__(self) -> None:
        for name in ("gain", "full_well", "electrons_per_unit"):
            if not getattr(self, name) > 0:
                raise ValueError(f"SensorParams.{name} must be > 0, got {getattr(self, name)}")
        if self.read_noise < 0 or self.black_level < 0:
            raise ValueError("SensorParams.read_noise and black_level must be >= 0")
        if not 1 <= self.bits <= 16:
            raise ValueError(f"SensorParams.bits must be in [1, 16], got {self.bits}")
        if not 0 < self.saturation <= 1:
            raise ValueError(f"SensorParams.saturation must be in (0, 1], got {self.saturation}")

    @property
    def white_level(self) -> int:
        """Largest raw value, ``2**bits - 1``."""
        return 2**self.bits - 1

    @property
    def dn_per_unit_second(self) -> float:
        """Black-subtracted DN per second for an analyzer intensity of 1."""
        return self.gain * self.electrons_per_unit


def _rgb(x: ArrayLike, name: str) -> tuple[float, float, float]:
    a = np.broadcast_to(np.asarray(x, dtype=np.float64), (3,))
    if not np.all(np.isfinite(a) | np.isinf(a)):
        raise ValueError(f"{name} must be numbers")
    return tuple(float(v) for v in a)  # type: ignore[return-value]


@dataclass(frozen=True)
class CameraModel:
    """Everything the forward model and the decoder need to know about the camera side of the rig.

    Attributes:
        qwp_angle: fast-axis angle of the quarter-wave plate in radians (0 = horizontal).
        qwp_retardance: retardance per colour channel (R, G, B) in radians; pi/2 is ideal. With
            ``pi/2 + e`` the decoded s3 becomes ``s3 + s2 * cot(pi/2 + e)`` (s2 leaks in).
        extinction_ratio: micro-polarizer extinction ratio per colour channel (``inf`` = ideal).
            Order 10^2 for this sensor family (Hagen et al., Opt. Eng. 58(8), 2019); calibrate.
        analyzer_transmittance: transmittance of a micro-polarizer along its axis.
        exposures: HDR bracket exposure times in seconds.
        sensor: the linear sensor model.
        pattern_offset: (row, col) of raw pixel (0, 0) inside the 4x4 IMX250MYR table.
    """

    qwp_angle: float = 0.0
    qwp_retardance: tuple[float, float, float] = (np.pi / 2, np.pi / 2, np.pi / 2)
    extinction_ratio: tuple[float, float, float] = (100.0, 100.0, 100.0)
    analyzer_transmittance: float = 1.0
    exposures: tuple[float, ...] = (0.010, 0.020, 0.100, 0.200)
    sensor: SensorParams = field(default_factory=SensorParams)
    pattern_offset: tuple[int, int] = (0, 0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "qwp_retardance", _rgb(self.qwp_retardance, "qwp_retardance"))
        object.__setattr__(self, "extinction_ratio", _rgb(self.extinction_ratio, "extinction_ratio"))
        object.__setattr__(self, "exposures", tuple(float(t) for t in self.exposures))
        object.__setattr__(self, "pattern_offset", tuple(int(v) % 4 for v in self.pattern_offset))
        if min(self.extinction_ratio) < 1:
            raise ValueError(f"extinction_ratio must be >= 1, got {self.extinction_ratio}")
        if not self.exposures or min(self.exposures) <= 0:
            raise ValueError(f"exposures must be positive seconds, got {self.exposures}")
        if not np.all(np.abs(np.sin(np.asarray(self.qwp_retardance))) > 0.1):
            raise ValueError("qwp_retardance too far from pi/2: s3 is not measurable")
        if not self.analyzer_transmittance > 0:
            raise ValueError("analyzer_transmittance must be > 0")

    def replace(self, **changes) -> CameraModel:
        """Return a copy with some fields changed (dataclasses.replace)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """JSON-friendly dictionary (inverse of :meth:`from_dict`)."""
        d = dataclasses.asdict(self)
        d["extinction_ratio"] = [v if np.isfinite(v) else "inf" for v in self.extinction_ratio]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> CameraModel:
        """Build from :meth:`to_dict` output; unknown keys raise ValueError naming them."""
        d = dict(d)
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown camera model keys {sorted(unknown)}; valid: {sorted(known)}")
        if "sensor" in d:
            s = dict(d["sensor"])
            sknown = {f.name for f in dataclasses.fields(SensorParams)}
            if set(s) - sknown:
                raise ValueError(f"unknown sensor keys {sorted(set(s) - sknown)}; valid: {sorted(sknown)}")
            d["sensor"] = SensorParams(**s)
        if "extinction_ratio" in d:
            d["extinction_ratio"] = [float(v) for v in np.broadcast_to(d["extinction_ratio"], (3,))]
        for key in ("qwp_retardance", "exposures", "pattern_offset"):
            if key in d:
                d[key] = tuple(np.atleast_1d(d[key]).tolist())
        return cls(**d)


def measurement_matrix(model: CameraModel) -> NDArray[np.float64]:
    """Intensity each analyzer records from an incoming Stokes vector, per colour channel.

    Row ``[c, a]`` is the first row of ``polarizer(angle_a, ER_c) @ retarder(delta_c, qwp_angle)``.

    Returns:
        ``(3, 4, 4)``: colour channel, analyzer angle (:data:`ANGLES_DEG`), Stokes component.
    """
    theta = np.deg2rad(np.asarray(ANGLES_DEG, dtype=np.float64))
    rows = []
    for c in range(3):
        pol = mueller.linear_polarizer(
            theta, extinction_ratio=model.extinction_ratio[c], transmittance=model.analyzer_transmittance
        )
        rows.append((pol @ mueller.retarder(model.qwp_retardance[c], model.qwp_angle))[:, 0, :])
    return np.stack(rows)


def mosaic_indices(pattern_offset: tuple[int, int] = (0, 0)) -> tuple[NDArray, NDArray]:
    """Colour and angle index of raw pixel ``(i, j)`` for ``i, j in 0..3``, given the ROI offset."""
    r, c = pattern_offset
    rows = (np.arange(4) + r) % 4
    cols = (np.arange(4) + c) % 4
    return MOSAIC_COLOR[np.ix_(rows, cols)], MOSAIC_ANGLE[np.ix_(rows, cols)]


def _check_stokes_image(stokes_rgb: NDArray) -> None:
    if stokes_rgb.ndim != 4 or stokes_rgb.shape[2:] != (3, 4):
        raise ValueError(f"stokes images must have shape (H, W, 3, 4); got {stokes_rgb.shape}")
    h, w = stokes_rgb.shape[:2]
    if h % 4 or w % 4:
        raise ValueError(f"image size must be a multiple of 4 (the mosaic period); got {h}x{w}")


def analyzer_intensities(stokes_rgb: ArrayLike, model: CameraModel) -> NDArray:
    """Intensity behind every analyzer for every colour; ``(H, W, 3, 4)`` -> ``(H, W, 3, 4)``."""
    s = np.asarray(stokes_rgb)
    if s.shape[-2:] != (3, 4):
        raise ValueError(f"stokes images must have shape (..., 3, 4); got {s.shape}")
    return np.einsum("cak,...ck->...ca", measurement_matrix(model).astype(s.dtype), s)


def mosaic(stokes_rgb: ArrayLike, model: CameraModel) -> NDArray:
    """Sample the analyzer intensities into the IMX250MYR mosaic; ``(H, W, 3, 4)`` -> ``(H, W)``.

    Only the intensity each pixel actually sees is computed (1/12 of :func:`analyzer_intensities`).
    """
    s = np.asarray(stokes_rgb)
    _check_stokes_image(s)
    a = measurement_matrix(model).astype(s.dtype if s.dtype == np.float32 else np.float64)
    color, angle = mosaic_indices(model.pattern_offset)
    out = np.empty(s.shape[:2], dtype=a.dtype)
    for i in range(4):
        for j in range(4):
            out[i::4, j::4] = s[i::4, j::4, color[i, j], :] @ a[color[i, j], angle[i, j]]
    return out


def expose(
    irradiance: ArrayLike,
    exposure: float,
    sensor: SensorParams,
    *,
    rng: np.random.Generator | None = None,
    noise: bool = True,
) -> NDArray[np.uint16]:
    """Turn per-pixel analyzer intensities into one raw frame.

    .. math::
        DN = \\mathrm{clip}(\\mathrm{round}(K (\\mathrm{Poisson}(\\mu_e) + N(0, \\sigma_r^2))) + b,\\ 0,\\ 2^{bits}-1),
        \\quad \\mu_e = \\min(\\text{electrons\\_per\\_unit} \\cdot I \\cdot t, \\text{full\\_well})

    so that ``Var(DN) = K (mean - b) + K^2 sigma_r^2 + 1/12`` below saturation (Foi et al., IEEE
    TIP 2008; EMVA 1288). Without noise only the rounding and clipping remain.

    Args:
        irradiance: analyzer intensity per pixel (the :func:`mosaic`), ``(H, W)``, >= 0.
        exposure: exposure time in seconds.
        sensor: sensor parameters.
        rng: random generator (required when ``noise`` is True).
        noise: draw shot and read noise.

    Returns:
        ``(H, W)`` uint16 raw frame.
    """
    x = np.asarray(irradiance, dtype=np.float64)
    if not np.all(np.isfinite(x)):
        raise ValueError("irradiance contains NaN or Inf")
    electrons = np.clip(x, 0.0, None) * (sensor.electrons_per_unit * exposure)
    if noise:
        if rng is None:
            raise ValueError("expose(noise=True) needs an rng")
        # Poisson with a huge mean overflows; the well clips anyway.
        electrons = rng.poisson(np.minimum(electrons, 4.0 * sensor.full_well)).astype(np.float64)
        electrons = np.minimum(electrons, sensor.full_well)
        electrons += rng.normal(0.0, sensor.read_noise, size=electrons.shape)
    else:
        electrons = np.minimum(electrons, sensor.full_well)
    dn = np.rint(sensor.gain * electrons) + sensor.black_level
    return np.clip(dn, 0, sensor.white_level).astype(np.uint16)


def simulate_capture(
    stokes_rgb: ArrayLike,
    model: CameraModel,
    *,
    rng: np.random.Generator | None = None,
    noise: bool = True,
) -> NDArray[np.uint16]:
    """Render the raw HDR bracket a real capture would give for these Stokes images.

    Args:
        stokes_rgb: Stokes images per colour channel in linear radiance units, ``(H, W, 3, 4)``
            with H and W multiples of 4.
        model: camera model (optics, sensor, exposure bracket).
        rng: random generator (required when ``noise`` is True).
        noise: draw Poisson-Gaussian noise.

    Returns:
        ``(E, H, W)`` uint16 raws, one per exposure in ``model.exposures``.
    """
    s = np.asarray(stokes_rgb)
    if not np.all(np.isfinite(s)):
        raise ValueError("stokes images contain NaN or Inf")
    irr = mosaic(s, model)
    return np.stack([expose(irr, t, model.sensor, rng=rng, noise=noise) for t in model.exposures])
