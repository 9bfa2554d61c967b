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
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pbrdf.polar import mueller
from pbrdf.sensor.imperfections import (
    IDENTITY3,
    IMPERFECTION_RANGES,
    apply_rig_imperfections,
    check_crosstalk,
    check_vignetting_poly,
)

__all__ = [
    "ANGLES_DEG",
    "MOSAIC_COLOR",
    "MOSAIC_ANGLE",
    "SENSOR_RANGES",
    "BITS_RANGE",
    "CAMERA_RANGES",
    "MAX_EXPOSURES",
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


#: Valid ranges ``(low, high)``, both inclusive, of the numeric :class:`SensorParams` fields.
#: Every corner decodes to finite maps (``tests/pbrdf/sensor/test_decode.py``).
SENSOR_RANGES = {
    "gain": (1e-4, 1e4),  # DN per electron
    "read_noise": (0.0, 1e6),  # electrons
    "full_well": (1.0, 1e9),  # electrons
    "black_level": (0.0, 65535.0),  # DN (and below saturation * white level)
    "electrons_per_unit": (1e-3, 1e12),  # electrons per second per unit of radiance
    "saturation": (0.5, 1.0),  # fraction of the white level
}
#: Valid range of ``SensorParams.bits``.
BITS_RANGE = (1, 16)
#: Valid ranges ``(low, high)``, both inclusive, of the :class:`CameraModel` fields (radians,
#: seconds, plain ratios). ``extinction_ratio`` may also be ``inf`` (an ideal polarizer);
#: ``qwp_retardance`` must further keep ``|sin| >= 0.1`` (s3 measurable).
CAMERA_RANGES = {
    "qwp_angle": (-2 * np.pi, 2 * np.pi),
    "qwp_retardance": (0.0, 2 * np.pi),
    "extinction_ratio": (2.0, np.inf),
    "analyzer_transmittance": (1e-3, 1.0),
    "exposures": (1e-7, 1e4),
}
#: Most exposures in one bracket.
MAX_EXPOSURES = 64


def _short(value: object, limit: int = 40) -> str:
    """``repr(value)`` cut to ``limit`` characters for error messages."""
    text = repr(value) if not isinstance(value, int) or value.bit_length() < 128 else f"{str(value)[:20]}..."
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _real(value: object, name: str, lo: float, hi: float) -> float:
    """``value`` as a float in ``[lo, hi]``; ValueError naming ``name`` and the range otherwise.

    ``inf`` passes only where ``hi`` is ``inf``; NaN, booleans, strings and ints too large for
    a float are refused.
    """
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ValueError(f"{name} must be a number in [{lo:g}, {hi:g}]; got {_short(value)}")
    try:
        x = float(value)
    except OverflowError:
        x = math.inf if value > 0 else -math.inf
    if not lo <= x <= hi or (math.isinf(x) and not math.isinf(hi)):
        raise ValueError(f"{name} must be in [{lo:g}, {hi:g}]; got {x:g}")
    return x


@dataclass(frozen=True)
class SensorParams:
    """Linear sensor model (EMVA 1288 style). Defaults: IMX250 family at 12 bit.

    Every field is checked on construction against :data:`SENSOR_RANGES` and
    :data:`BITS_RANGE` (ValueError naming the field and its valid range), and the black level
    must lie below the saturation threshold ``saturation * white_level`` (else no pixel can
    ever be measured).

    Attributes:
        gain: system gain K in DN per electron (about 0.38 for the IMX250 at 12 bit);
            ``[1e-4, 1e4]``.
        read_noise: temporal dark noise in electrons (about 2.95 e-); ``[0, 1e6]``.
        full_well: saturation capacity in electrons (about 10.7 ke-); ``[1, 1e9]``.
        black_level: offset added to every pixel, in DN; ``[0, saturation * white_level)``.
        bits: ADC bit depth, an integer in ``[1, 16]``; the white level is ``2**bits - 1``.
        electrons_per_unit: photo-electrons per second produced by an analyzer intensity of 1 in
            the renderer's linear radiance units (the radiometric calibration of the rig). The
            default makes ``s0 = 1`` fill about 75 % of the well in the shortest bracket;
            ``[1e-3, 1e12]``.
        saturation: fraction of the white level from which a pixel counts as saturated;
            ``[0.5, 1]``.
    """

    gain: float = 0.38
    read_noise: float = 2.95
    full_well: float = 10700.0
    black_level: float = 16.0
    bits: int = 12
    electrons_per_unit: float = 8.0e5
    saturation: float = 0.95

    def __post_init__(self) -> None:
        for name, (lo, hi) in SENSOR_RANGES.items():
            object.__setattr__(self, name, _real(getattr(self, name), f"SensorParams.{name}", lo, hi))
        bits = self.bits
        if isinstance(bits, float) and bits.is_integer():
            bits = int(bits)
        lo, hi = BITS_RANGE
        if isinstance(bits, bool) or not isinstance(bits, int | np.integer) or not lo <= bits <= hi:
            raise ValueError(f"SensorParams.bits must be an integer in [{lo}, {hi}]; got {_short(bits)}")
        object.__setattr__(self, "bits", int(bits))
        threshold = self.saturation * self.white_level
        if not self.black_level < threshold:
            raise ValueError(
                f"SensorParams.black_level {self.black_level:g} must be below the saturation threshold "
                f"{threshold:g} DN (saturation x white level {self.white_level} = 2**bits - 1)"
            )

    @property
    def white_level(self) -> int:
        """Largest raw value, ``2**bits - 1``."""
        return 2**self.bits - 1

    @property
    def dn_per_unit_second(self) -> float:
        """Black-subtracted DN per second for an analyzer intensity of 1."""
        return self.gain * self.electrons_per_unit


def _rgb(x: object, name: str, lo: float, hi: float) -> tuple[float, float, float]:
    """One number or three (R, G, B), each in ``[lo, hi]``, as a tuple of three floats."""
    values = list(x) if isinstance(x, list | tuple | np.ndarray) else [x]
    if isinstance(x, np.ndarray) and x.ndim == 0:
        values = [x.item()]
    if len(values) == 1:
        values = values * 3
    if len(values) != 3:
        raise ValueError(f"{name} must be one number or three (R, G, B); got {len(values)} values")
    return tuple(_real(v, f"{name}[{c}]", lo, hi) for c, v in zip("RGB", values, strict=True))  # type: ignore[return-value]


@dataclass(frozen=True)
class CameraModel:
    """Everything the forward model and the decoder need to know about the camera side of the rig.

    Every field is checked on construction against :data:`CAMERA_RANGES` (ValueError naming the
    field and its valid range): out-of-range calibration would decode to all-zero, NaN or
    meaningless maps.

    Attributes:
        qwp_angle: fast-axis angle of the quarter-wave plate in radians (0 = horizontal);
            ``[-2 pi, 2 pi]``.
        qwp_retardance: retardance per colour channel (R, G, B) in radians; pi/2 is ideal. With
            ``pi/2 + e`` the decoded s3 becomes ``s3 + s2 * cot(pi/2 + e)`` (s2 leaks in).
            ``[0, 2 pi]`` with ``|sin| >= 0.1``.
        extinction_ratio: micro-polarizer extinction ratio per colour channel (``inf`` = ideal).
            Order 10^2 for this sensor family (Hagen et al., Opt. Eng. 58(8), 2019); calibrate.
            ``[2, inf]``: at 1 the analyzers do not polarize and LP and CP cannot be measured.
        analyzer_transmittance: transmittance of a micro-polarizer along its axis; ``[1e-3, 1]``.
        exposures: HDR bracket exposure times in seconds, 1 to :data:`MAX_EXPOSURES` of them,
            each in ``[1e-7, 1e4]``.
        sensor: the linear sensor model.
        pattern_offset: (row, col) of raw pixel (0, 0) inside the 4x4 IMX250MYR table; two
            integers, taken modulo 4.
        ambient: unpolarized ambient radiance per camera channel (R, G, B), added to ``s0``;
            ``[0, 1e4]``, nominal 0. The decoder removes it with a dark frame.
        crosstalk: 3 x 3 spectral mixing, rows camera channel, columns display colour region;
            entries in ``[0, 1]``, condition number <= 100, nominal identity.
        vignetting_focal_px: focal length in pixels of the cos^4 falloff; ``[1, inf]``, nominal
            ``inf`` (none).
        vignetting_poly: ``(k1, k2, k3)`` of the falloff polynomial in the normalised radius;
            each in ``[-10, 10]`` and the polynomial >= 0.05 over the frame; nominal 0.
        (The three imperfection terms: :mod:`pbrdf.sensor.imperfections`.)
    """

    qwp_angle: float = 0.0
    qwp_retardance: tuple[float, float, float] = (np.pi / 2, np.pi / 2, np.pi / 2)
    extinction_ratio: tuple[float, float, float] = (100.0, 100.0, 100.0)
    analyzer_transmittance: float = 1.0
    exposures: tuple[float, ...] = (0.010, 0.020, 0.100, 0.200)
    sensor: SensorParams = field(default_factory=SensorParams)
    pattern_offset: tuple[int, int] = (0, 0)
    ambient: tuple[float, float, float] = (0.0, 0.0, 0.0)
    crosstalk: tuple[tuple[float, ...], ...] = IDENTITY3
    vignetting_focal_px: float = math.inf
    vignetting_poly: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        self._check_imperfections()
        rng = CAMERA_RANGES
        object.__setattr__(self, "qwp_angle", _real(self.qwp_angle, "qwp_angle (radians)", *rng["qwp_angle"]))
        ret = _rgb(self.qwp_retardance, "qwp_retardance (radians)", *rng["qwp_retardance"])
        object.__setattr__(self, "qwp_retardance", ret)
        er = _rgb(self.extinction_ratio, "extinction_ratio", *rng["extinction_ratio"])
        object.__setattr__(self, "extinction_ratio", er)
        object.__setattr__(
            self,
            "analyzer_transmittance",
            _real(self.analyzer_transmittance, "analyzer_transmittance", *rng["analyzer_transmittance"]),
        )
        exposures = self.exposures
        if isinstance(exposures, np.ndarray):
            exposures = exposures.tolist()
        if not isinstance(exposures, list | tuple) or not 1 <= len(exposures) <= MAX_EXPOSURES:
            raise ValueError(f"exposures must be a list of 1 to {MAX_EXPOSURES} times (s); got {_short(exposures)}")
        lo, hi = rng["exposures"]
        object.__setattr__(self, "exposures", tuple(_real(t, "exposures (seconds)", lo, hi) for t in exposures))
        po = self.pattern_offset
        if isinstance(po, np.ndarray):
            po = po.tolist()
        if not isinstance(po, list | tuple) or len(po) != 2:
            raise ValueError(f"pattern_offset must be two integers (row, col); got {_short(po)}")
        offsets = []
        for v in po:
            if isinstance(v, float) and v.is_integer():
                v = int(v)
            if isinstance(v, bool) or not isinstance(v, int | np.integer):
                raise ValueError(f"pattern_offset must be two integers (row, col); got {_short(po)}")
            offsets.append(int(v) % 4)
        object.__setattr__(self, "pattern_offset", tuple(offsets))
        if not isinstance(self.sensor, SensorParams):
            raise ValueError(f"sensor must be a SensorParams; got {type(self.sensor).__name__}")
        if min(abs(math.sin(d)) for d in self.qwp_retardance) < 0.1:
            raise ValueError(
                f"qwp_retardance {self.qwp_retardance} too far from pi/2: s3 is not measurable (needs |sin| >= 0.1)"
            )

    def _check_imperfections(self) -> None:
        rng = IMPERFECTION_RANGES
        object.__setattr__(self, "ambient", _rgb(self.ambient, "ambient", *rng["ambient"]))
        object.__setattr__(self, "crosstalk", check_crosstalk(self.crosstalk))
        focal = _real(self.vignetting_focal_px, "vignetting_focal_px", *rng["vignetting_focal_px"])
        object.__setattr__(self, "vignetting_focal_px", focal)
        poly = self.vignetting_poly
        if not isinstance(poly, list | tuple | np.ndarray) or len(poly) != 3:
            raise ValueError(f"vignetting_poly must be three numbers (k1, k2, k3); got {_short(poly)}")
        poly = tuple(_real(k, f"vignetting_poly[{i}]", *rng["vignetting_poly"]) for i, k in enumerate(poly))
        check_vignetting_poly(poly)
        object.__setattr__(self, "vignetting_poly", poly)

    @property
    def nominal_rig(self) -> bool:
        """True when ambient, cross-talk and vignetting are all nominal (the decoder skips them)."""
        return (
            not any(self.ambient)
            and self.crosstalk == IDENTITY3
            and math.isinf(self.vignetting_focal_px)
            and not any(self.vignetting_poly)
        )

    def replace(self, **changes) -> CameraModel:
        """Return a copy with some fields changed (dataclasses.replace)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """JSON-friendly dictionary (inverse of :meth:`from_dict`)."""
        d = dataclasses.asdict(self)
        d["extinction_ratio"] = [v if np.isfinite(v) else "inf" for v in self.extinction_ratio]
        d["vignetting_focal_px"] = self.vignetting_focal_px if np.isfinite(self.vignetting_focal_px) else "inf"
        d["crosstalk"] = [list(row) for row in self.crosstalk]
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
            if not isinstance(d["sensor"], dict | SensorParams):
                raise ValueError(f"sensor must be an object of sensor fields; got {type(d['sensor']).__name__}")
            if isinstance(d["sensor"], dict):
                s = dict(d["sensor"])
                sknown = {f.name for f in dataclasses.fields(SensorParams)}
                if set(s) - sknown:
                    raise ValueError(f"unknown sensor keys {sorted(set(s) - sknown)}; valid: {sorted(sknown)}")
                d["sensor"] = SensorParams(**s)
        if "extinction_ratio" in d:
            er = d["extinction_ratio"]
            er = er if isinstance(er, list | tuple) else [er]
            d["extinction_ratio"] = [math.inf if isinstance(v, str) and v.strip().lower() == "inf" else v for v in er]
        vf = d.get("vignetting_focal_px")
        if isinstance(vf, str) and vf.strip().lower() == "inf":
            d["vignetting_focal_px"] = math.inf
        if "exposures" in d and not isinstance(d["exposures"], list | tuple | np.ndarray):
            d["exposures"] = [d["exposures"]]  # one exposure given as a bare number
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
        model: camera model (optics, sensor, exposure bracket, rig imperfections: the Stokes colour
            axis is then the display colour region, see :mod:`pbrdf.sensor.imperfections`).
        rng: random generator (required when ``noise`` is True).
        noise: draw Poisson-Gaussian noise.

    Returns:
        ``(E, H, W)`` uint16 raws, one per exposure in ``model.exposures``.
    """
    s = np.asarray(stokes_rgb)
    if not np.all(np.isfinite(s)):
        raise ValueError("stokes images contain NaN or Inf")
    _check_stokes_image(s)
    irr = mosaic(s if model.nominal_rig else apply_rig_imperfections(s, model), model)
    return np.stack([expose(irr, t, model.sensor, rng=rng, noise=noise) for t in model.exposures])
