"""Numerical stress: no public function of the polarimetry and microfacet modules returns NaN or Inf.

Every public function of :mod:`pbrdf.polar.mueller`, :mod:`pbrdf.polar.stokes`,
:mod:`pbrdf.polar.fresnel` and :mod:`pbrdf.brdf.microfacet` is called on every combination of
extreme arguments (zeros, subnormals, 1e15, 1e154, 1e200, 1e308, their negatives, Inf and NaN;
Jones entries near 1e200 and 1e300j; directions with components near 1e200): each call either
raises ValueError (naming the argument) or returns finite values. There is no allow-list: a new
public function needs a case here (``test_every_public_function_has_a_case``).
"""

from __future__ import annotations

import inspect
import itertools
import warnings

import numpy as np
import pytest

from pbrdf.brdf import microfacet
from pbrdf.polar import fresnel, mueller, stokes

MODULES = (mueller, stokes, fresnel, microfacet)
S = [0.0, -0.0, 5e-324, 0.5, -1.0, 1e15, 1e154, 1e308, -1e308, np.inf, -np.inf, np.nan]
SMALL = [0.0, 5e-324, 0.5, 1e200, -1e308, np.inf, np.nan]
VEC3 = [np.array(v, dtype=np.float64) for v in (
    [0, 0, 1], [0.6, 0, 0.8], [1e200, 0, 1e200], [0, 0, 1e200], [1e150, 0, 1e150], [1e-200, 0, 1e-200], [0, 0, 0],
    [0, 0, -1], [1e308, 1e308, 1e308], [np.nan, 0, 1], [np.inf, 0, 1], [0, 0, 5e-324])]  # fmt: skip
#: Fewer directions for the functions of several direction arguments (their products grow fast).
DIRS = [VEC3[i] for i in (0, 1, 2, 4, 6, 9)]
VEC4 = [np.array(v, dtype=np.float64) for v in (
    [1, 0, 0, 0], [1, 1, 0, 0], [0, 0, 0, 0], [1e308] * 4, [1e200, 1e200, 0, 0], [5e-324, 5e-324, 0, 0],
    [np.nan, 0, 0, 0], [np.inf, 0, 0, 0], [-1, 0, 0, 0])]  # fmt: skip
MAT4 = [np.eye(4), np.full((4, 4), 1e200), np.full((4, 4), 1e308), np.full((4, 4), 5e-324), np.full((4, 4), np.nan)]
JONES = [np.eye(2, dtype=complex), np.array([[1e200, 0], [0, 1]]), np.array([[1e300j, 0], [0, 1]]),
         np.array([[1e154, 1e154j], [1, 1]]), np.array([[5e-324, 0], [0, 1e-300]]), np.array([[np.nan, 0], [0, 1]]),
         np.array([[1e308, 1e308], [1e308j, 1e308]])]  # fmt: skip
ETA = [1.5, 0.5, 1e-300, 1e308, 0.18 - 3.2j, 1e200j, 1e308 + 1e308j, np.nan, np.inf, 0.0, -1.0]
ALPHA = [0.0, 0.5, 1e200, np.nan]
ETA_REAL = [1.5, 1.0, 1e-300, 1e308, 0.0, np.nan]

#: function name -> (callable, pools of arguments); every combination is called.
CASES = {
    "apply": (mueller.apply, [MAT4, VEC4]),
    "rotator": (mueller.rotator, [S]),
    "rotate_element": (mueller.rotate_element, [MAT4, S]),
    "linear_polarizer": (lambda t, e, q: mueller.linear_polarizer(t, extinction_ratio=e, transmittance=q), [S, S, S]),
    "linear_diattenuator": (mueller.linear_diattenuator, [S, S, S]),
    "retarder": (mueller.retarder, [S, S]),
    "qwp": (mueller.qwp, [S]),
    "hwp": (mueller.hwp, [S]),
    "depolarizer": (mueller.depolarizer, [S]),
    "diagonal_depolarizer": (mueller.diagonal_depolarizer, [S, SMALL, SMALL]),
    "jones_to_mueller": (mueller.jones_to_mueller, [JONES]),
    "stokes_basis": (mueller.stokes_basis, [VEC3]),
    "rotate_stokes_basis": (mueller.rotate_stokes_basis, [VEC3, VEC3, VEC3]),
    "rotate_mueller_basis": (lambda m, f, c, t: mueller.rotate_mueller_basis(m, f, c, t, f, c, t),
                             [MAT4, DIRS, DIRS, DIRS]),
    "stokes": (stokes.stokes, [S, SMALL, S, S]),
    "intensity": (stokes.intensity, [VEC4]),
    "dop": (stokes.dop, [VEC4]),
    "dolp": (stokes.dolp, [VEC4]),
    "docp": (stokes.docp, [VEC4]),
    "aolp": (stokes.aolp, [VEC4]),
    "ellipticity_angle": (stokes.ellipticity_angle, [VEC4]),
    "is_physical_stokes": (stokes.is_physical_stokes, [VEC4]),
    "conductor_extinction": (fresnel.conductor_extinction, [S, [1.0, 0.2, 1e308, np.nan, 0.0]]),
    "dielectric_transmittance": (lambda c, e: fresnel.dielectric_transmittance(np.asarray(c, float), e), [S, ETA_REAL]),
    "fresnel_amplitudes": (fresnel.fresnel_amplitudes, [S, ETA]),
    "fresnel_reflectance": (fresnel.fresnel_reflectance, [S, ETA]),
    "reflection_mueller": (fresnel.reflection_mueller, [S, ETA]),
    "transmission_mueller": (fresnel.transmission_mueller, [S, ETA]),
    "ggx_d": (microfacet.ggx_d, [S, S]),
    "smith_g1": (microfacet.smith_g1, [S, S]),
    "dielectric_pbrdf": (lambda wi, wo, a, e: microfacet.dielectric_pbrdf(wi, wo, albedo=0.5, eta=e, alpha=a),
                         [DIRS, DIRS, ALPHA, ETA_REAL]),
    "conductor_pbrdf": (lambda wi, wo, a, e: microfacet.conductor_pbrdf(wi, wo, eta=e, alpha=a),
                        [DIRS, DIRS, ALPHA, [0.18 - 3.2j, 1e200j, 1e308 + 0j, 0j]]),
}  # fmt: skip


def _finite(out) -> bool:
    outs = out if isinstance(out, tuple) else (out,)
    return all(np.isfinite(np.asarray(o)).all() for o in outs)


def test_every_public_function_has_a_case():
    public = {
        name
        for module in MODULES
        for name in module.__all__
        if inspect.isfunction(getattr(module, name)) or inspect.isbuiltin(getattr(module, name))
    }
    assert public == set(CASES), f"missing: {sorted(public - set(CASES))}, unknown: {sorted(set(CASES) - public)}"


@pytest.mark.parametrize("name", sorted(CASES))
def test_no_nan_or_inf_leaves_a_public_function(name):
    fn, pools = CASES[name]
    bad = []
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nor a RuntimeWarning on the way
        for args in itertools.product(*pools):
            try:
                out = fn(*args)
            except ValueError:
                continue
            except Exception as exc:  # noqa: BLE001 (the point: anything but ValueError is a failure)
                bad.append((args, type(exc).__name__))
                continue
            if not _finite(out):
                bad.append((args, "NaN or Inf"))
    assert not bad, f"{len(bad)} calls of {name}, e.g. {bad[:3]}"


@pytest.mark.parametrize(
    ("call", "finite"),
    [
        (lambda: mueller.linear_polarizer(1e308), True),
        (lambda: mueller.retarder(np.pi / 2, -1e308), True),
        (lambda: mueller.jones_to_mueller([[1e200, 0], [0, 1]]), False),
        (lambda: mueller.jones_to_mueller([[1e300j, 0], [0, 1]]), False),
        (lambda: microfacet.dielectric_pbrdf([0, 0, 1.0], [1e200, 0, 1e200], albedo=0.5, eta=1.5, alpha=0.0), False),
    ],
)
def test_the_calls_named_in_the_issue(call, finite):
    """Huge angles come back finite (the rotation is periodic); overflowing inputs are refused by name."""
    if finite:
        assert np.isfinite(call()).all()
    else:
        with pytest.raises(ValueError, match="jones|wo must hold finite unit vectors"):
            call()


def test_a_huge_angle_is_the_same_rotation_as_its_remainder():
    t = 1e308
    np.testing.assert_allclose(mueller.rotator(t), mueller.rotator(np.remainder(t, np.pi)), atol=0)
    np.testing.assert_allclose(mueller.rotator(0.3), mueller.rotator(0.3 + 4 * np.pi), atol=1e-14)
