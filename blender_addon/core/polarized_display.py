"""The display as a linearly polarized area emitter, for the ``*_mono_polarized`` JIT variants.

Mitsuba's emitters emit unpolarized light, so the physical model of the LCD is an unpolarized
``area`` emitter behind a ``polarizer`` sheet (:func:`.mitsuba_scene.display_shapes`). Every
shadow ray then crosses the sheet as a null interface, which only ``volpath`` follows, at the
cost of extra intersections and Mueller products per ray. This emitter puts the sheet's effect
into the emission instead: light leaving the display along the unit direction ``k`` is fully
linearly polarized along ``t = k x a`` (normalised), where ``a`` is the sheet's absorbing axis,
with the sheet's 50 % transmission folded into the radiance. That is the tilted-polarizer model
of Korger et al. 2013 that Mitsuba's ``polarizer`` uses, so both routes give the same Stokes
images (tested to noise, plastic and metal); the scene needs no sheet, and ``path`` (cheaper than
``volpath``) does next-event estimation to the display.

The Stokes vector is expressed in Mitsuba's implicit basis of the propagation direction,
``x = mueller.stokes_basis(k)`` and ``y = k x x``: with ``u = k x a``,

.. math:: S = L \\left(1,\\ \\frac{(u \\cdot x)^2 - (u \\cdot y)^2}{|u|^2},\\
          \\frac{2 (u \\cdot x)(u \\cdot y)}{|u|^2},\\ 0\\right),

returned as the first column of the emitted Mueller matrix (the ``stokes`` integrator reads the
first column of the path's Mueller product). Only the front side emits, as Mitsuba's ``area``.
The radiance may fall with the emission angle ``theta`` from the front normal as ``cos^p theta``
(``display.emission_exponent``, :mod:`pbrdf.sensor.display_response`; 0 = flat, as before).
Sampling is the shape's (uniform in area, converted to solid angle), so the emitter must sit on a
``rectangle`` (or any shape) through the shape dict's ``emitter`` entry.
"""

from __future__ import annotations

from typing import Any

from .mono_plugins import register_once

__all__ = ["PLUGIN", "register", "emitter_dict"]

#: Mitsuba plugin name of this emitter (registered per variant by :func:`register`).
PLUGIN = "pdir_polarized_display"


def emitter_dict(
    radiance: float, absorbing_axis: Any, degree_of_polarization: float = 1.0, emission_exponent: float = 0.0
) -> dict:
    """The Mitsuba dict of a polarized display emitter (register the plugin first).

    Args:
        radiance: S0 of the light leaving the display (after the polarizer), linear units.
        absorbing_axis: ``(3,)`` world direction of the polarizer's absorbing axis, in the
            display plane (perpendicular to the transmitted polarization at normal incidence).
        degree_of_polarization: in [0, 1]; the emitted S1 and S2 are scaled by it (a partially
            polarized display: the polarized part plus unpolarized light of the same S0).
        emission_exponent: ``p`` of the angular profile ``cos^p`` of the emission angle; >= 0.
    """
    ax = [float(x) for x in absorbing_axis]
    if len(ax) != 3 or sum(x * x for x in ax) == 0.0:
        raise ValueError(f"absorbing_axis must be a non-zero 3-vector, got {absorbing_axis!r}")
    if not 0.0 <= degree_of_polarization <= 1.0:
        raise ValueError(f"degree_of_polarization must be in [0, 1], got {degree_of_polarization}")
    if not 0.0 <= emission_exponent < float("inf"):
        raise ValueError(f"emission_exponent must be a finite number >= 0, got {emission_exponent}")
    out = {"type": PLUGIN, "radiance": float(radiance), "absorbing_axis": ax}
    if degree_of_polarization != 1.0:  # the fully polarized display's dict (and kernels) stay as before
        out["dop"] = float(degree_of_polarization)
    if emission_exponent != 0.0:  # likewise the flat display's
        out["exponent"] = float(emission_exponent)
    return out


def register() -> None:
    """Register :data:`PLUGIN` with Mitsuba for the current (mono-polarized JIT) variant, once."""
    register_once(PLUGIN, "emitter", _emitter_class)


def _emitter_class() -> type:
    """The emitter class, deriving from the current variant's ``mi.Emitter``."""
    import drjit as dr  # noqa: PLC0415
    import mitsuba as mi  # noqa: PLC0415

    class PolarizedDisplay(mi.Emitter):
        """``pdir_polarized_display``: ``radiance``, ``absorbing_axis`` (3 floats), ``dop`` (1), ``exponent`` (0)."""

        def __init__(self, props: Any) -> None:
            mi.Emitter.__init__(self, props)
            self.radiance = float(props.get("radiance", 1.0))
            a = [float(x) for x in props.get("absorbing_axis")]
            norm = sum(x * x for x in a) ** 0.5
            self.axis = [x / norm for x in a]
            self.dop = float(props.get("dop", 1.0))
            self.exponent = float(props.get("exponent", 0.0))
            # A partially polarized display is the engine's drawn rig, other values every scene: the axis and
            # DoP become kernel parameters (opaque) so scenes share compiled kernels; the default keeps literals.
            self.partial = self.dop != 1.0
            if self.partial:
                self.opaque_axis = dr.opaque(mi.Vector3f, self.axis)
                self.opaque_dop = dr.opaque(mi.Float, self.dop)
            # Likewise the profile's exponent (drawn per scene too); a flat display keeps its kernels.
            self.profiled = self.exponent != 0.0
            if self.profiled:
                self.opaque_exponent = dr.opaque(mi.Float, self.exponent)
            self.m_flags = mi.EmitterFlags.Surface

        def _emitted(self, k, scale, active, cos_theta):
            """Mueller matrix whose first column is the Stokes vector emitted along ``k``, times ``scale``.

            ``cos_theta``: cosine of the emission angle (from the front normal), for the profile.
            """
            if self.profiled:  # cos^p; the clamp keeps the power finite (emission at exactly 90 deg is 0 anyway)
                scale = scale * dr.power(dr.maximum(cos_theta, 1e-12), self.opaque_exponent)
            u = dr.cross(k, self.opaque_axis if self.partial else mi.Vector3f(*self.axis))
            x = mi.mueller.stokes_basis(k)
            y = dr.cross(k, x)
            ux, uy = dr.dot(u, x), dr.dot(u, y)
            n2 = dr.fma(ux, ux, uy * uy)
            # Along the absorbing axis itself (grazing emission) no direction is singled out.
            inv = dr.select(n2 > 1e-12, dr.rcp(n2), 0.0)
            m = dr.zeros(mi.Spectrum)
            s = dr.select(active, scale, 0.0)
            m[0, 0] = s
            if self.partial:  # S1, S2 scaled (a Python branch: the fully polarized kernel is unchanged)
                inv = inv * self.opaque_dop
            m[1, 0] = s * (ux * ux - uy * uy) * inv
            m[2, 0] = s * 2.0 * ux * uy * inv
            return m

        def eval(self, si, active=True):
            front = active & (mi.Frame3f.cos_theta(si.wi) > 0)
            return self._emitted(si.to_world(si.wi), self.radiance, front, mi.Frame3f.cos_theta(si.wi))

        def sample_direction(self, it, sample, active=True):
            ds = self.get_shape().sample_direction(it, sample, active)
            ok = active & (dr.dot(ds.d, ds.n) < 0) & (ds.pdf > 0)
            ds.emitter = mi.EmitterPtr(self)
            scale = self.radiance * dr.rcp(dr.select(ok, ds.pdf, 1.0))
            return ds, self._emitted(-ds.d, scale, ok, -dr.dot(ds.d, ds.n))

        def pdf_direction(self, it, ds, active=True):
            pdf = self.get_shape().pdf_direction(it, ds, active)
            return dr.select(active & (dr.dot(ds.d, ds.n) < 0), pdf, 0.0)

        def eval_direction(self, it, ds, active=True):
            return self._emitted(-ds.d, self.radiance, active & (dr.dot(ds.d, ds.n) < 0), -dr.dot(ds.d, ds.n))

        def sample_position(self, time, sample, active=True):
            raise NotImplementedError(f"{PLUGIN} supports camera paths only (no light tracing)")

        def sample_ray(self, time, sample1, sample2, sample3, active=True):
            raise NotImplementedError(f"{PLUGIN} supports camera paths only (no light tracing)")

        def sample_wavelengths(self, si, sample, active=True):
            return mi.UnpolarizedSpectrum(1.0), mi.UnpolarizedSpectrum(1.0)

        def traverse(self, callback) -> None:
            pass

        def to_string(self) -> str:
            return (
                f"PolarizedDisplay[radiance={self.radiance}, absorbing_axis={self.axis}, dop={self.dop}, "
                f"exponent={self.exponent}]"
            )

    return PolarizedDisplay
