"""A pBRDF table at one wavelength as a Mitsuba BSDF for the ``*_mono_polarized`` passes.

The mono passes of :mod:`.render` render one colour channel at a time, so a table is only ever
evaluated at that channel's wavelength. This BSDF interpolates the table along wavelength once, in
numpy (:func:`channel_matrices`), and keeps the 16 Mueller entries of each grid cell together in
one flat Dr.Jit array over ``(phi_d, theta_d, theta_h)``: one trilinear interpolation (8 corners,
one gather per entry and corner), where Mitsuba's ``measured_polarized`` runs a 4-D ``Marginal2D``
lookup (four interval searches and 16 corners) per entry. Everything else follows the plugin
(``src/bsdfs/measured_polarized.cpp``, Mitsuba 3.9): the standard frame and Rusinkiewicz angles,
the plane-of-reflection Stokes frames rotated into Mitsuba's implicit bases, a zero matrix where
the interpolated ``m00`` is NaN, ``m00 >= 0``, times ``cos theta_o``; importance sampling mixes 10 %
cosine-weighted and 90 % GGX visible-normal samples of roughness ``alpha_sample``. The evaluation
equals the plugin's to float32 round-off and renders are the same to 1e-6 (tested).

Entries that cannot matter are not fetched (:func:`needed_entries`): those below
:data:`NEGLIGIBLE` times ``m00`` in every cell and band (the circular-linear couplings ``m03,
m13, m30, m31`` of the generated tables stay below 1e-3 of it), and with
``linear_light`` the last column, which only multiplies incident ``S3``: direct light from the
linearly polarized display has ``S3 = 0``. Each table lookup reads 16 values at 8 corners, most of
the BSDF's cost; a generated table needs 10 of the 16 in direct light.

Unlike the plugin's, its data and ``alpha_sample`` are JIT parameters (``mi.traverse``: ``data``
and ``alpha_sample``): switching the channel is a parameter update, and neither the table's
values nor the roughness is compiled into Dr.Jit's kernels (only which entries it fetches). Axes
must be uniform (grid indices are affine in the angles; :func:`uniform_axes`); other tables use
the plugin.
Its speed against the plugin's is in docs/measurements/headless.md.
"""

from __future__ import annotations

import functools
import os
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pbrdf.io.tensorfile import read_tensor_file

from .mono_plugins import register_once

__all__ = ["PLUGIN", "COSINE_WEIGHT", "NEGLIGIBLE", "channel_matrices", "needed_entries", "uniform_axes", "register"]

#: Mitsuba plugin name of this BSDF (registered per variant by :func:`register`).
PLUGIN = "pdir_table"
#: Share of cosine-weighted hemisphere samples in the importance sampling (the plugin's value).
COSINE_WEIGHT = 0.1
#: Entries below this fraction of ``m00`` in every cell are not fetched: they change no Stokes
#: component by more than 0.2 % of S0, a tenth of the renders' 2 % noise target.
NEGLIGIBLE = 2e-3
_AXES = ("phi_d", "theta_d", "theta_h")


def _axes(fields: dict) -> list[NDArray[np.float64]]:
    return [np.asarray(fields[k], dtype=np.float64).reshape(-1) for k in _AXES]


def uniform_axes(path: str | os.PathLike) -> bool:
    """Whether the table's ``phi_d``, ``theta_d`` and ``theta_h`` are uniform grids of 2 or more values."""
    for a in _axes(read_tensor_file(path)):
        if len(a) < 2 or not np.allclose(np.diff(a), (a[-1] - a[0]) / (len(a) - 1), rtol=1e-4, atol=1e-6):
            return False
    return True


def channel_matrices(
    path: str | os.PathLike, wavelength: float
) -> tuple[NDArray[np.float32], list[NDArray[np.float64]]]:
    """The table's Mueller matrices at one wavelength, and its angle axes.

    Interpolates linearly between the two bands around ``wavelength``, clamped at the ends, as
    the plugin's lookup does (a NaN in either band gives NaN, even at weight 0).

    Returns:
        ``(M, [phi_d, theta_d, theta_h])`` with ``M`` of shape ``(Np, Nd, Nh, 16)`` float32
        (row-major 4 x 4 entries).
    """
    fields = read_tensor_file(path)
    bands = np.asarray(fields["wvls"], dtype=np.float64).reshape(-1)
    m = fields["M"]
    if len(bands) == 1:
        out = np.asarray(m[..., 0, :, :], dtype=np.float32)
    else:
        i = int(np.clip(np.searchsorted(bands, wavelength, side="right") - 1, 0, len(bands) - 2))
        w = float(np.clip((wavelength - bands[i]) / (bands[i + 1] - bands[i]), 0.0, 1.0))
        lo = np.asarray(m[..., i, :, :], dtype=np.float32)
        hi = np.asarray(m[..., i + 1, :, :], dtype=np.float32)
        out = np.float32(1.0 - w) * lo + np.float32(w) * hi
    return np.ascontiguousarray(out.reshape(*out.shape[:3], 16)), _axes(fields)


def needed_entries(path: str | os.PathLike, *, linear_light: bool = False) -> tuple[int, ...]:
    """Row-major indices of the Mueller entries the BSDF must fetch from a table.

    An entry is left out where its magnitude is at most :data:`NEGLIGIBLE` times ``|m00|`` in
    every cell and band (non-finite values count as needed), and with
    ``linear_light`` the last column (3, 7, 11, 15) is left out as well: it multiplies the
    incident ``S3``, which is 0 for light that is unpolarized or linearly polarized. ``m00`` is
    always fetched (its NaN marks invalid cells).

    Returns:
        sorted entry indices in ``0..15``.
    """
    st = os.stat(path)  # the answer is cached per file version: every colour pass of every scene asks
    return _needed_entries(os.path.realpath(path), st.st_mtime_ns, st.st_size, bool(linear_light))


@functools.lru_cache(maxsize=256)
def _needed_entries(path: str, mtime_ns: int, size: int, linear_light: bool) -> tuple[int, ...]:
    m = np.asarray(read_tensor_file(path)["M"], dtype=np.float64)
    m = m.reshape(-1, 16)
    finite = np.isfinite(m)
    a = np.abs(np.where(finite, m, 0.0))
    floor = 1e-12 * a[:, 0].max()  # float round-off where m00 is 0
    needed = (a > NEGLIGIBLE * a[:, :1] + floor).any(axis=0) | ~finite.all(axis=0)
    needed[0] = True
    if linear_light:
        needed[[3, 7, 11, 15]] = False
    return tuple(int(e) for e in np.flatnonzero(needed))


def register() -> None:
    """Register :data:`PLUGIN` with Mitsuba for the current (mono-polarized JIT) variant, once."""
    register_once(PLUGIN, "bsdf", _bsdf_class)


def _bsdf_class() -> type:
    """The BSDF class, deriving from the current variant's ``mi.BSDF``.

    Kept in one piece: a Mitsuba plugin class must derive from the ``mi.BSDF`` of the variant set
    when it is registered, so the class (and its helper ``rotate_z``) is defined in this one closure,
    called once per variant by :func:`register`.
    """
    import drjit as dr  # noqa: PLC0415
    import mitsuba as mi  # noqa: PLC0415

    def rotate_z(v, sin, cos):
        return mi.Vector3f(cos * v.x - sin * v.y, sin * v.x + cos * v.y, v.z)

    class TableBSDF(mi.BSDF):
        """``pdir_table``: ``filename``, ``wavelength`` (nm), ``alpha_sample`` (0.1), ``linear_light`` (false)."""

        def __init__(self, props: Any) -> None:
            mi.BSDF.__init__(self, props)
            self.m_flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            self.m_components = [self.m_flags]
            self.name = os.path.basename(str(props["filename"]))
            data, axes = channel_matrices(props["filename"], float(props["wavelength"]))
            self.data = mi.Float(data.reshape(-1))
            # Grid index t = (x - x0) / step per axis; sizes, origins and steps are opaque, so
            # that tables with other grids reuse the kernel too.
            self.size = dr.opaque(mi.Vector3u, [len(a) for a in axes])
            self.origin = dr.opaque(mi.Vector3f, [float(a[0]) for a in axes])
            self.inv_step = dr.opaque(mi.Vector3f, [float((len(a) - 1) / (a[-1] - a[0])) for a in axes])
            self.alpha = dr.opaque(mi.Float, float(props.get("alpha_sample", 0.1)))
            # Fixed per table: a table with other negligible entries compiles its own kernel.
            self.entries = needed_entries(props["filename"], linear_light=bool(props.get("linear_light", False)))

        def traverse(self, callback) -> None:
            callback.put("data", self.data, mi.ParamFlags.NonDifferentiable)
            callback.put("alpha_sample", self.alpha, mi.ParamFlags.NonDifferentiable)

        def parameters_changed(self, keys: list[str]) -> None:
            pass

        def _lookup(self, angles, active) -> list:
            """Multilinear interpolation of the 16 entries at ``(phi_d, theta_d, theta_h)``, clamped at the ends."""
            lower, weight = [], []
            for k in range(3):
                t = (angles[k] - self.origin[k]) * self.inv_step[k]
                i0 = mi.UInt32(dr.clip(mi.Int32(dr.floor(t)), 0, mi.Int32(self.size[k]) - 2))
                lower.append(i0)
                weight.append(dr.clip(t - mi.Float(i0), 0.0, 1.0))
            entries = [mi.Float(0.0) for _ in range(16)]  # literal zeros where not fetched
            for corner in range(8):
                bit = [(corner >> k) & 1 for k in range(3)]
                w = mi.Float(1.0)
                for k in range(3):
                    w = w * (weight[k] if bit[k] else 1.0 - weight[k])
                index = ((lower[0] + bit[0]) * self.size[1] + lower[1] + bit[1]) * self.size[2] + lower[2] + bit[2]
                for e in self.entries:
                    entries[e] = dr.fma(w, dr.gather(mi.Float, self.data, index * 16 + e, active), entries[e])
            return entries

        def _mueller(self, wo_hat, wi_hat, active):
            """Table value in Mitsuba's implicit bases (no cos factor); radiance-mode roles."""
            phi = dr.atan2(wi_hat.y, wi_hat.x)
            sin, cos = dr.sincos(phi)
            wo_std, wi_std = rotate_z(wo_hat, -sin, cos), rotate_z(wi_hat, -sin, cos)
            # Rusinkiewicz angles of (i = wo_std, o = wi_std), as the plugin computes them.
            h = dr.normalize(wo_std + wi_std)
            b = dr.normalize(dr.cross(mi.Vector3f(0, 0, 1), h))
            t = dr.normalize(dr.cross(b, h))
            theta_d = dr.safe_acos(dr.dot(h, wo_std))
            theta_h = dr.safe_acos(h.z)
            i_prj = dr.normalize(wo_std - dr.dot(wo_std, h) * h)
            phi_d = dr.atan2(dr.clip(dr.dot(b, i_prj), -1.0, 1.0), dr.clip(dr.dot(t, i_prj), -1.0, 1.0))
            entries = self._lookup((phi_d, theta_d, theta_h), active)
            bad = dr.isnan(entries[0])
            entries[0] = dr.maximum(entries[0], 0.0)
            value = mi.Spectrum(*[dr.select(bad, 0.0, e) for e in entries])
            # Plane-of-reflection frames (the plugin's Fig. 4 of Baek et al. 2020), back to the surface frame.
            zo = -wo_std
            yo = dr.normalize(dr.cross(dr.normalize(dr.cross(wo_std - wi_std, zo)), zo))
            yi = dr.normalize(dr.cross(dr.normalize(dr.cross(wi_std - wo_std, wi_std)), wi_std))
            xo = rotate_z(dr.cross(yo, zo), sin, cos)
            xi = rotate_z(dr.cross(yi, wi_std), sin, cos)
            return mi.mueller.rotate_mueller_basis(
                value, -wo_hat, xo, mi.mueller.stokes_basis(-wo_hat), wi_hat, xi, mi.mueller.stokes_basis(wi_hat)
            )

        def eval(self, ctx, si, wo, active=True):
            active = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
            radiance = ctx.mode == mi.TransportMode.Radiance
            value = self._mueller(wo if radiance else si.wi, si.wi if radiance else wo, active)
            return dr.select(active, value * mi.Frame3f.cos_theta(wo), 0.0)

        def pdf(self, ctx, si, wo, active=True):
            distr = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, self.alpha, self.alpha, True)
            h = dr.normalize(wo + si.wi)
            p = COSINE_WEIGHT * mi.warp.square_to_cosine_hemisphere_pdf(wo) + (1.0 - COSINE_WEIGHT) * distr.pdf(
                si.wi, h
            ) / (4.0 * dr.dot(wo, h))
            return dr.select((mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0), p, 0.0)

        def sample(self, ctx, si, sample1, sample2, active=True):
            active = active & (mi.Frame3f.cos_theta(si.wi) > 0)
            distr = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, self.alpha, self.alpha, True)
            m, _ = distr.sample(si.wi, sample2)
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = dr.select(
                sample1 < COSINE_WEIGHT, mi.warp.square_to_cosine_hemisphere(sample2), mi.reflect(si.wi, m)
            )
            bs.pdf = self.pdf(ctx, si, bs.wo, active)
            bs.eta = 1.0
            bs.sampled_component = 0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
            value = self.eval(ctx, si, bs.wo, active)
            return bs, dr.select(active & (bs.pdf > 0), value / bs.pdf, 0.0)

        def to_string(self) -> str:
            return f"TableBSDF[{self.name}]"

    return TableBSDF
