"""pBRDF tables: the table type, table files, resampling and evaluation against Mitsuba.

Mitsuba references are Mitsuba 3.9.1's own code run on real files written in ``tmp_path``:
``mitsuba.tensor_io`` (Python writer/reader of the tensor format) and the C++
``measured_polarized`` plugin through ``bsdf.eval`` in ``scalar_spectral_polarized`` (one
evaluation at a time, four wavelengths per call) and ``llvm_ad_mono_polarized`` (vectorised, one
wavelength).

Tolerance against Mitsuba: the plugin computes in float32 (directions, angles, interpolation
weights, frame rotations) on the same float32 table, while :func:`pbrdf.brdf.table.evaluate` uses
float64. Both interpolate the same grid linearly, so the difference is float32 round-off times
the table's slope. Measured worst case relative to max|M|: 3.2e-6 for the Fresnel (gold) table
over 2000 pairs half of them near the specular lobe (llvm_ad_mono_polarized), 5.3e-7 for the
random smooth table over 1000 pairs x 4 wavelengths in both transport modes
(scalar_spectral_polarized). We allow ``2e-5 * max|M|``, which also covers the plugin's float32
``acos`` (up to 3e-4 rad near theta_d = 0 or theta_h = 0, times the per-radian slope of these
tables).
"""

from __future__ import annotations

import numpy as np
import pytest

from pbrdf.brdf import table as tbl
from pbrdf.brdf.rusinkiewicz import rusinkiewicz_from_directions
from pbrdf.brdf.table import PBRDFTable, evaluate, load_table, resample, save_table, to_mitsuba_bands
from pbrdf.io import tensorfile
from pbrdf.io.tensorfile import read_tensor_file, write_tensor_file
from pbrdf.polar import fresnel, mueller
from tests.helpers import random_hemisphere

PI = np.pi
MI_REL_TOL = 2e-5  # times max|M|; see the module docstring
# The LLVM tests share one table shape and wavelength, so that Dr.Jit compiles one kernel (~8 s cold)
# and reuses it (the plugin bakes the grid sizes and its ``wavelength`` into the kernel).
MONO_GRID = {"n_phi": 9, "n_d": 31, "n_h": 31}
MONO_WAVELENGTH = 575.0
KAIST_WAVELENGTHS = np.array([450.0, 500.0, 550.0, 600.0, 650.0])
HPBRDF_WAVELENGTHS = np.arange(414.0, 951.0, 8.0)  # 68 bands, 414..950 nm


# --- helpers -----------------------------------------------------------------------------------------


def _bits(a):
    """Bit patterns, so that -0.0 vs 0.0 and NaN payloads count as differences."""
    a = np.ascontiguousarray(a)
    return a.view(f"u{a.dtype.itemsize}") if a.dtype.kind == "f" else a


def grid(n_phi=13, n_d=10, n_h=10, wavelengths=KAIST_WAVELENGTHS):
    """Rusinkiewicz axes over the full ranges and a meshgrid ``(Np, Nd, Nh, W)`` of them."""
    axes = (np.linspace(-PI, PI, n_phi), np.linspace(0, PI / 2, n_d), np.linspace(0, PI / 2, n_h), wavelengths)
    return axes, np.meshgrid(*axes, indexing="ij")


def lambertian_table(albedo=0.8, **kw):
    axes, mesh = grid(**kw)
    m = np.zeros((*mesh[0].shape, 4, 4), np.float32)
    m[..., 0, 0] = albedo / PI
    return PBRDFTable(*axes, m, name="lambertian")


def smooth_random_table(rng, wavelengths=KAIST_WAVELENGTHS, **kw):
    """Random entries affine in cos/sin(phi_d), theta_d, theta_h and wavelength; m00 around 3.

    It depends on the sign of phi_d and on every axis, so any mistake in the angle conventions,
    the frame rotations or the interpolation shows up.
    """
    axes, (p, d, h, lam) = grid(wavelengths=wavelengths, **kw)
    c = rng.normal(size=(6, 4, 4)) * 0.2
    terms = (np.ones_like(p), np.cos(p), np.sin(p), d, h, (lam - 550.0) / 100.0)
    m = sum(ci * ti[..., None, None] for ci, ti in zip(c, terms, strict=True))
    m[..., 0, 0] += 3.0  # positive and still affine in every term (max |random part| ~ 2 here)
    return PBRDFTable(*axes, m.astype(np.float32), name="smooth_random")


def fresnel_table(**kw):
    """Glossy gold-like conductor plus a diffuse floor, in the plugin's s/p frames.

    ``M = kd / pi * E00 + ks * D(theta_h) * F(theta_d; eta(lambda))`` with the Fresnel Mueller matrix
    of pbrdf.polar.fresnel (x-axis perpendicular to the plane of reflection) and a Gaussian-like D.
    The complex eta (0.27 - 2.78i at 550 nm, shifted with wavelength) gives circular terms.
    """
    axes, (_, d, h, lam) = grid(**kw)
    eta = (0.27 + 0.002 * (lam - 550.0)) - 1j * (2.78 + 0.004 * (lam - 550.0))
    f = fresnel.reflection_mueller(np.cos(d), eta)
    lobe = np.exp(-((np.tan(np.minimum(h, 1.4)) / 0.4) ** 2))
    m = 0.6 * lobe[..., None, None] * f
    m[..., 0, 0] += 0.05 / PI
    return PBRDFTable(*axes, m.astype(np.float32), name="fresnel_gold")


def f32_unit(v):
    """Unit vectors exactly as Mitsuba gets them (float32), in float64."""
    return np.asarray(v, np.float32).astype(np.float64)


def assert_close_to_mitsuba(ours, theirs, scale):
    err = np.abs(ours - theirs).max(axis=(-2, -1))
    k = int(np.argmax(err))
    assert err[k] <= MI_REL_TOL * scale, f"pair {k}: error {err[k]:.3g}\nours\n{ours[k]}\nmitsuba\n{theirs[k]}"


def mi_eval_scalar(mi, path, wi, wo, wavelengths, *, mode="radiance"):
    """``bsdf.eval`` in scalar_spectral_polarized: ``wavelengths (n, 4)`` -> ``(n, 4, 4, 4)`` (last axis: lambda)."""
    bsdf = mi.load_dict({"type": "measured_polarized", "filename": str(path)})
    ctx = mi.BSDFContext(mi.TransportMode.Radiance if mode == "radiance" else mi.TransportMode.Importance)
    out = []
    for a, o, lam in zip(np.float32(wi), np.float32(wo), np.float32(wavelengths), strict=True):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(a)
        si.wavelengths = mi.UnpolarizedSpectrum(lam)
        out.append(np.array(bsdf.eval(ctx, si, mi.Vector3f(o))))  # (4, 4, 4) = (row, col, lambda)
    return np.stack(out)


def mi_eval_mono(mi, path, wi, wo, wavelength):
    """Vectorised ``bsdf.eval`` in llvm_ad_mono_polarized at one wavelength: ``(n, 4, 4)``."""
    import drjit as dr

    bsdf = mi.load_dict({"type": "measured_polarized", "filename": str(path), "wavelength": float(wavelength)})
    si = dr.zeros(mi.SurfaceInteraction3f, len(wi))
    si.wi = mi.Vector3f(np.float32(wi).T)
    value = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(np.float32(wo).T))
    return np.moveaxis(np.array(value)[:, :, 0, :], -1, 0)  # (4, 4, 1, n) -> (n, 4, 4)


# --- table files -------------------------------------------------------------------------------------


def raw_table_fields(table):
    """The fields as the KAIST/hpBRDF files have them (no metadata field)."""
    return {
        "theta_h": table.theta_h.astype(np.float32)[None],
        "theta_d": table.theta_d.astype(np.float32)[None],
        "phi_d": table.phi_d.astype(np.float32)[None],
        "wvls": table.wavelengths.astype(np.uint16),
        "M": table.M,
    }


class TestTableFiles:
    def test_round_trip(self, tmp_path, rng):
        t = smooth_random_table(rng)
        m = t.M.copy()
        m[3, 2, 1, 4] = np.nan  # a raw NaN bin survives
        t = PBRDFTable(t.phi_d, t.theta_d, t.theta_h, t.wavelengths, m, name="x", metadata={"source": "test", "n": 3})
        back = load_table(save_table(tmp_path / "x.pbsdf", t))
        for name in ("phi_d", "theta_d", "theta_h"):
            np.testing.assert_array_equal(getattr(back, name), getattr(t, name).astype(np.float32))
        np.testing.assert_array_equal(back.wavelengths, t.wavelengths)
        np.testing.assert_array_equal(_bits(back.M), _bits(t.M))
        assert back.name == "x" and back.metadata == {"source": "test", "n": 3}
        assert back.nan_mask.sum() == 1 and back.nan_mask[3, 2, 1, 4]
        fields = read_tensor_file(tmp_path / "x.pbsdf")
        assert {k: (v.dtype.str, v.shape) for k, v in fields.items() if k != "metadata_json"} == {
            "phi_d": ("<f4", (1, 13)),
            "theta_d": ("<f4", (1, 10)),
            "theta_h": ("<f4", (1, 10)),
            "wvls": ("<u2", (5,)),
            "M": ("<f4", (13, 10, 10, 5, 4, 4)),
        }

    @pytest.mark.parametrize(
        ("filename", "wavelengths"),
        [("1_spectralon_inpainted.pbsdf", KAIST_WAVELENGTHS), ("Aluminum.hpbrdf", HPBRDF_WAVELENGTHS)],
    )
    def test_dataset_files_load_with_the_same_reader(self, tmp_path, rng, filename, wavelengths):
        t = smooth_random_table(rng, wavelengths=wavelengths, n_phi=9, n_d=6, n_h=6)
        path = write_tensor_file(tmp_path / filename, raw_table_fields(t))
        back = load_table(path)
        assert back.name == filename.rsplit(".", 1)[0] and back.metadata == {}
        assert back.shape == (9, 6, 6, wavelengths.size)
        np.testing.assert_array_equal(back.wavelengths, wavelengths)
        np.testing.assert_array_equal(_bits(back.M), _bits(t.M))
        assert isinstance(back.M, np.memmap) == (t.M.nbytes >= tensorfile._MMAP_MIN_BYTES)

    def test_large_table_is_memory_mapped(self, tmp_path):
        t = lambertian_table(n_phi=37, n_d=19, n_h=19)  # 4.3 MB
        back = load_table(save_table(tmp_path / "l.pbsdf", t))
        assert isinstance(back.M, np.memmap) and not back.M.flags.writeable
        assert not isinstance(load_table(tmp_path / "l.pbsdf", mmap=False).M, np.memmap)

    def test_for_mitsuba_zeroes_nan_bins(self, tmp_path):
        t = lambertian_table()
        m = t.M.copy()
        m[1, 2, 3, 0] = np.nan
        m[4, 0, 0, 2, 1, 3] = np.nan  # one NaN entry makes the whole bin invalid
        t = PBRDFTable(t.phi_d, t.theta_d, t.theta_h, t.wavelengths, m)
        back = load_table(save_table(tmp_path / "m.pbsdf", t, for_mitsuba=True))
        assert np.isfinite(back.M).all()
        assert not back.M[1, 2, 3, 0].any() and not back.M[4, 0, 0, 2].any()
        keep = ~t.nan_mask
        np.testing.assert_array_equal(back.M[keep], t.M[keep])

    def test_save_errors(self, tmp_path):
        t = lambertian_table(wavelengths=HPBRDF_WAVELENGTHS, n_phi=3, n_d=2, n_h=2)
        with pytest.raises(ValueError, match="68 bands.*to_mitsuba_bands"):
            save_table(tmp_path / "a.pbsdf", t, for_mitsuba=True)
        half = PBRDFTable(t.phi_d, t.theta_d, t.theta_h, t.wavelengths + 0.5, t.M)
        with pytest.raises(ValueError, match="whole nanometres"):
            save_table(tmp_path / "a.pbsdf", half)
        odd = PBRDFTable(t.phi_d, t.theta_d, t.theta_h, t.wavelengths, t.M, metadata={"f": object()})
        with pytest.raises(ValueError, match="JSON"):
            save_table(tmp_path / "a.pbsdf", odd)
        assert not list(tmp_path.iterdir())

    def test_load_errors(self, tmp_path):
        t = lambertian_table(n_phi=3, n_d=2, n_h=2)
        fields = raw_table_fields(t)
        write_tensor_file(tmp_path / "nom.pbsdf", {k: v for k, v in fields.items() if k not in ("M", "wvls")})
        with pytest.raises(ValueError, match=r"missing field\(s\) 'wvls', 'M'"):
            load_table(tmp_path / "nom.pbsdf")
        # Mitsuba's spectralon_lowres.pbsdf fixture stores its axes as (0, N).
        write_tensor_file(tmp_path / "fixture.pbsdf", {**fields, "phi_d": np.zeros((0, 3), np.float32)})
        with pytest.raises(ValueError, match="'phi_d' has shape \\(0, 3\\) and stores no axis values"):
            load_table(tmp_path / "fixture.pbsdf")
        write_tensor_file(tmp_path / "f64.pbsdf", {**fields, "M": fields["M"].astype(np.float64)})
        with pytest.raises(ValueError, match="'M' must be float32"):
            load_table(tmp_path / "f64.pbsdf")
        write_tensor_file(tmp_path / "shape.pbsdf", {**fields, "M": fields["M"][:, :1]})
        with pytest.raises(ValueError, match=r"shape.pbsdf: PBRDFTable.M must have shape"):
            load_table(tmp_path / "shape.pbsdf")


class TestPBRDFTable:
    def test_validation_names_the_field(self):
        (p, d, h, w), _ = grid(n_phi=3, n_d=2, n_h=2)
        m = np.zeros((3, 2, 2, 5, 4, 4), np.float32)
        bad = {
            "phi_d": ((p[::-1], d, h, w, m), "phi_d must be strictly increasing"),
            "phi range": ((p * 1.1, d, h, w, m), r"phi_d must lie in \[-3.14"),
            "theta_d range": ((p, d - 0.1, h, w, m), "theta_d must lie in"),
            "theta_h range": ((p, d, h * 1.1, w, m), "theta_h must lie in"),
            "theta_h ndim": ((p, d, h[None], w, m), "theta_h must be a non-empty 1-D array"),
            "wavelengths": ((p, d, h, w - 1000, m), "wavelengths must lie in"),
            "nan axis": ((p, d, [0.0, np.nan], w, m), "theta_h must be finite"),
            "M shape": (
                (p, d, h, w, m[:, :, :, :4]),
                r"M must have shape \(Np, Nd, Nh, W, 4, 4\) = \(3, 2, 2, 5, 4, 4\)",
            ),
            "M dtype": ((p, d, h, w, m.astype(bool)), "M must be a real"),
        }
        for args, match in bad.values():
            with pytest.raises(ValueError, match=match):
                PBRDFTable(*args)
        with pytest.raises(ValueError, match="metadata must be a dict"):
            PBRDFTable(p, d, h, w, m, metadata=[1])

    def test_float32_axes_accepted_and_immutable(self):
        (p, d, h, w), _ = grid(n_phi=3, n_d=2, n_h=2)
        t = PBRDFTable(
            p.astype(np.float32), d.astype(np.float32), h.astype(np.float32), w, np.zeros((3, 2, 2, 5, 4, 4))
        )
        assert t.phi_d[-1] > PI and t.M.dtype == np.float32  # float32(pi) rounds up
        with pytest.raises(ValueError, match="read-only"):
            t.theta_d[0] = 1.0
        with pytest.raises(AttributeError):
            t.name = "other"

    def test_nan_mask_and_masked(self, monkeypatch):
        t = lambertian_table(n_phi=5, n_d=3, n_h=3)
        t.M[2, 1, 0, 3, 2, 2] = np.nan
        t.M[4, 2, 2, 0] = np.nan
        monkeypatch.setattr(tbl, "_CHUNK_BYTES", 1)  # one phi_d slab at a time
        mask = t.nan_mask
        assert mask.shape == (5, 3, 3, 5) and mask.sum() == 2 and mask[2, 1, 0, 3] and mask[4, 2, 2, 0]
        ma = t.masked()
        assert ma.mask[2, 1, 0, 3].all() and not ma.mask[2, 1, 0, 2].any()
        assert ma[..., 0, 0].mean() == pytest.approx(0.8 / PI)


# --- resampling --------------------------------------------------------------------------------------


class TestResample:
    def test_identity_is_exact(self, rng):
        t = smooth_random_table(rng)
        t.M[0, 1, 2, 3] = np.nan
        same = resample(t, phi_d=t.phi_d, theta_d=t.theta_d, theta_h=t.theta_h, wavelengths=t.wavelengths)
        np.testing.assert_array_equal(_bits(same.M), _bits(t.M))
        assert same.name == t.name

    def test_grid_points_are_copied_exactly(self, rng):
        """Targets on source samples (a subset) reproduce them bit for bit, NaN bins included."""
        t = smooth_random_table(rng)
        t.M[4, 3, 2, 1] = np.nan
        sub = resample(t, phi_d=t.phi_d[::2], theta_d=t.theta_d[1::2], wavelengths=t.wavelengths[[1, 3]])
        np.testing.assert_array_equal(_bits(sub.M), _bits(t.M[::2, 1::2][:, :, :, [1, 3]]))

    def test_linear_data_resamples_exactly(self, rng):
        """Affine in theta_d, theta_h and wavelength: multilinear interpolation reproduces it (float32 round-off)."""
        axes, (_, d, h, lam) = grid()
        a, b, c, e = rng.normal(size=(4, 4, 4))
        m = a + b * d[..., None, None] + c * h[..., None, None] + e * ((lam - 550) / 100)[..., None, None]
        t = PBRDFTable(*axes, m.astype(np.float32))
        new_d, new_h, new_w = rng.uniform(0, PI / 2, 7), rng.uniform(0, PI / 2, 6), np.array([455.0, 512.5, 649.0])
        r = resample(t, theta_d=np.sort(new_d), theta_h=np.sort(new_h), wavelengths=new_w)
        _, d2, h2, l2 = np.meshgrid(t.phi_d, np.sort(new_d), np.sort(new_h), new_w, indexing="ij")
        expected = a + b * d2[..., None, None] + c * h2[..., None, None] + e * ((l2 - 550) / 100)[..., None, None]
        np.testing.assert_allclose(r.M, expected, rtol=0, atol=2e-6)  # float32 storage of the source and result

    def test_phi_d_is_periodic(self):
        """A grid without the +pi sample: targets in the gap interpolate between the last and first samples."""
        phi = np.linspace(-PI, PI, 13)[:-1]  # step 30 degrees, last sample at 150 degrees
        m = np.zeros((12, 2, 2, 1, 4, 4), np.float32)
        m[..., 0, 0] = np.arange(12.0)[:, None, None, None]  # 11 at 150 deg, 0 at -180 deg
        t = PBRDFTable(phi, [0.0, 1.0], [0.0, 1.0], [550.0], m)
        r = resample(t, phi_d=np.radians([-175.0, -165.0, 165.0, 175.0]))
        np.testing.assert_allclose(r.M[:, 0, 0, 0, 0, 0], [1 / 6, 0.5, 5.5, 11 / 6], atol=1e-6)
        # A full grid: -pi and +pi are both samples, queries beyond them wrap around.
        full = PBRDFTable(
            np.linspace(-PI, PI, 13), [0.0], [0.0], [550.0], np.arange(13.0).reshape(13, 1, 1, 1, 1, 1) * np.eye(4)
        )
        r = resample(full, phi_d=[-PI + 0.25, PI - 0.25])
        np.testing.assert_allclose(r.M[:, 0, 0, 0, 0, 0], [0.25 / (PI / 6), 12 - 0.25 / (PI / 6)], atol=1e-6)

    def test_other_axes_clamp(self, rng):
        t = smooth_random_table(rng)
        r = resample(t, theta_d=[PI / 2], wavelengths=[100.0])  # below 450 nm: the 450 nm band
        np.testing.assert_array_equal(r.M[:, 0, :, 0], t.M[:, -1, :, 0])

    def test_nan_bins_use_finite_neighbours(self):
        m = np.zeros((1, 3, 1, 1, 4, 4), np.float32)
        m[0, :, 0, 0] = np.array([1.0, np.nan, 3.0])[:, None, None] * np.eye(4)
        t = PBRDFTable([0.0], [0.0, 0.5, 1.0], [0.0], [550.0], m)
        r = resample(t, theta_d=[0.25, 0.5, 0.75, 1.0])
        np.testing.assert_array_equal(r.M[0, :, 0, 0, 0, 0], [1.0, np.nan, 3.0, 3.0])  # renormalised, NaN at the bin
        both_nan = t.M.copy()
        both_nan[0, 0] = np.nan
        r = resample(PBRDFTable(t.phi_d, t.theta_d, t.theta_h, t.wavelengths, both_nan), theta_d=[0.2])
        assert np.isnan(r.M).all()

    def test_chunked_equals_unchunked(self, rng, monkeypatch):
        t = smooth_random_table(rng)
        t.M[5, 5, 5] = np.nan
        targets = {"phi_d": np.sort(rng.uniform(-PI, PI, 9)), "theta_h": np.sort(rng.uniform(0, 1.5, 4))}
        whole = resample(t, **targets)
        monkeypatch.setattr(tbl, "_CHUNK_BYTES", 1)  # one output phi_d row at a time
        np.testing.assert_array_equal(_bits(resample(t, **targets).M), _bits(whole.M))

    def test_bad_target(self, rng):
        with pytest.raises(ValueError, match="theta_d must lie in"):
            resample(smooth_random_table(rng), theta_d=[0.0, 2.0])

    def test_to_mitsuba_bands(self, rng):
        t = smooth_random_table(rng, wavelengths=HPBRDF_WAVELENGTHS, n_phi=5, n_d=4, n_h=4)
        five = to_mitsuba_bands(t)
        np.testing.assert_array_equal(five.wavelengths, [414, 548, 682, 816, 950])
        # The source is affine in wavelength, so the 5 samples are exact; 414 and 950 are source bands.
        np.testing.assert_array_equal(_bits(five.M[..., [0, -1], :, :]), _bits(t.M[..., [0, -1], :, :]))
        assert to_mitsuba_bands(five) is five
        np.testing.assert_array_equal(to_mitsuba_bands(t, max_bands=1).wavelengths, [682])
        with pytest.raises(ValueError, match="max_bands"):
            to_mitsuba_bands(t, max_bands=0)


# --- evaluation against Mitsuba ----------------------------------------------------------------------


class TestEvaluateAgainstMitsuba:
    def test_lambertian(self, tmp_path, rng, mi_variant):
        t = lambertian_table(albedo=0.8, **MONO_GRID)
        path = save_table(tmp_path / "lambert.pbsdf", t)
        wi, wo = f32_unit(random_hemisphere(rng, 50)), f32_unit(random_hemisphere(rng, 50))
        expected = np.zeros((50, 4, 4))
        expected[:, 0, 0] = 0.8 / PI * wo[:, 2]
        ours = evaluate(t, wi, wo, MONO_WAVELENGTH)
        np.testing.assert_allclose(ours, expected, rtol=1e-6, atol=1e-12)  # float32 albedo / pi
        mono = mi_eval_mono(mi_variant("llvm_ad_mono_polarized"), path, wi, wo, MONO_WAVELENGTH)
        np.testing.assert_allclose(mono, expected, rtol=1e-5, atol=1e-7)
        spec = mi_eval_scalar(mi_variant("scalar_spectral_polarized"), path, wi[:20], wo[:20], np.full((20, 4), 520.0))
        np.testing.assert_allclose(spec, np.repeat(expected[:20, :, :, None], 4, axis=-1), rtol=1e-5, atol=1e-7)

    def test_fresnel_table_mono(self, tmp_path, rng, mi_variant):
        """Glossy gold: all 16 entries, including the signs of the linear (m10, m20) and circular terms."""
        t = fresnel_table(**MONO_GRID)
        path = save_table(tmp_path / "gold.pbsdf", t)
        wi, wo = f32_unit(random_hemisphere(rng, 200)), f32_unit(random_hemisphere(rng, 200))
        # Half of the pairs near the specular lobe, where the polarization is strong.
        mirror = wo[:100] * [-1, -1, 1] + rng.normal(scale=0.1, size=(100, 3))
        wi[:100] = f32_unit(mirror / np.linalg.norm(mirror, axis=-1, keepdims=True))
        wi[:100, 2] = np.abs(wi[:100, 2])
        theirs = mi_eval_mono(mi_variant("llvm_ad_mono_polarized"), path, wi, wo, MONO_WAVELENGTH)
        ours = evaluate(t, wi, wo, MONO_WAVELENGTH)
        assert_close_to_mitsuba(ours, theirs, np.abs(t.M).max())
        # The comparison is not vacuous: strong linear and circular terms of both signs.
        for r, c in ((1, 0), (2, 0), (2, 3), (3, 2)):
            assert ours[:, r, c].min() < -0.01 and ours[:, r, c].max() > 0.01, (r, c)

    @pytest.mark.parametrize("mode", ["radiance", "importance"])
    def test_smooth_random_table_spectral(self, tmp_path, rng, mi_variant, mode):
        """Every axis, the phi_d sign, four interior wavelengths per call, both transport modes."""
        t = smooth_random_table(rng, n_phi=37, n_d=19, n_h=19)
        path = save_table(tmp_path / "r.pbsdf", t)
        n = 200
        wi, wo = f32_unit(random_hemisphere(rng, n)), f32_unit(random_hemisphere(rng, n))
        lam = np.float32(rng.uniform(440.0, 660.0, (n, 4))).astype(np.float64)  # 440, 660: clamped ends
        theirs = mi_eval_scalar(mi_variant("scalar_spectral_polarized"), path, wi, wo, lam, mode=mode)
        ours = evaluate(t, wi[:, None], wo[:, None], lam, mode=mode)  # (n, 4, 4, 4) = (pair, lambda, row, col)
        theirs = np.moveaxis(theirs, -1, 1)
        assert_close_to_mitsuba(ours.reshape(-1, 4, 4), theirs.reshape(-1, 4, 4), np.abs(t.M).max())

    def test_nan_bins_like_mitsuba(self, tmp_path, rng, mi_variant):
        """Raw NaN bins kept in the file: a zero matrix wherever one enters the interpolation, in both."""
        t = smooth_random_table(rng, n_phi=9, n_d=7, n_h=7)
        bad = rng.random(t.shape[:3]) < 0.2
        t.M[bad] = np.nan
        path = save_table(tmp_path / "nan.pbsdf", t)
        wi, wo = f32_unit(random_hemisphere(rng, 200)), f32_unit(random_hemisphere(rng, 200))
        lam = np.array([450.0, 530.0, 575.0, 650.0])
        theirs = mi_eval_scalar(mi_variant("scalar_spectral_polarized"), path, wi, wo, np.tile(lam, (200, 1)))
        theirs = np.moveaxis(theirs, -1, 1).reshape(-1, 4, 4)
        ours = evaluate(t, wi[:, None], wo[:, None], lam).reshape(-1, 4, 4)
        zero = ~ours.any(axis=(-2, -1))
        assert 80 < zero.sum() < 760 and np.isfinite(ours).all()
        assert_close_to_mitsuba(ours, theirs, np.nanmax(np.abs(t.M)))

    def test_to_mitsuba_bands_interior_wavelength(self, tmp_path, rng, mi_variant):
        """68 -> 5 bands; Mitsuba at interior wavelengths (600 nm lies between the bands 548 and 682)
        equals ours on the 5-band table and, as the source is affine in wavelength, ours on the
        68-band table."""
        t68 = smooth_random_table(rng, wavelengths=HPBRDF_WAVELENGTHS, n_phi=13, n_d=10, n_h=10)
        t5 = to_mitsuba_bands(t68)
        path = save_table(tmp_path / "hp5.pbsdf", t5, for_mitsuba=True)
        wi, wo = f32_unit(random_hemisphere(rng, 100)), f32_unit(random_hemisphere(rng, 100))
        lam = np.array([420.0, 600.0, 777.0, 901.0])
        theirs = mi_eval_scalar(mi_variant("scalar_spectral_polarized"), path, wi, wo, np.tile(lam, (100, 1)))
        theirs = np.moveaxis(theirs, -1, 1).reshape(-1, 4, 4)
        scale = np.abs(t68.M).max()
        assert_close_to_mitsuba(evaluate(t5, wi[:, None], wo[:, None], lam).reshape(-1, 4, 4), theirs, scale)
        assert_close_to_mitsuba(evaluate(t68, wi[:, None], wo[:, None], lam).reshape(-1, 4, 4), theirs, scale)

    def test_pin_mitsuba_degenerate_geometry(self, tmp_path, mi_variant):
        """Pins of the plugin at measure-zero geometry (Mitsuba 3.9.1); ours is finite in both cases.

        * Exact mirror configuration (h = n): the plugin's b = normalize(n x h) is NaN. The scalar
          variant then returns a zero matrix (a black highlight centre); the LLVM variant returns the
          same finite matrix as ours for a table that is phi_d-independent at theta_h = 0 (as an
          isotropic material is).
        * wi == wo (retro-reflection): the plugin's plane of reflection is undefined and both
          variants return NaN in the linear rows and columns; ours uses the plane of incidence.
        """
        t = fresnel_table(**MONO_GRID)
        path = save_table(tmp_path / "gold.pbsdf", t)
        s, c = np.sin(0.5), np.cos(0.5)
        wi = np.array([[s, 0, c], [s, 0, c]])
        wo = np.array([[-s, 0, c], [s, 0, c]])  # mirror, retro
        ours = evaluate(t, wi, wo, MONO_WAVELENGTH)
        assert np.isfinite(ours).all() and ours[0, 0, 0] > 0.1 and ours[1, 0, 0] > 0.01

        mono = mi_eval_mono(mi_variant("llvm_ad_mono_polarized"), path, wi, wo, MONO_WAVELENGTH)
        assert_close_to_mitsuba(ours[:1], mono[:1], np.abs(t.M).max())
        assert np.isnan(mono[1, 1:3]).all()

        spectral = mi_eval_scalar(
            mi_variant("scalar_spectral_polarized"), path, wi, wo, np.full((2, 4), MONO_WAVELENGTH)
        )
        assert not spectral[0].any()
        assert np.isnan(spectral[1, 1:3]).all()


# --- evaluate: physics and numerical stress ----------------------------------------------------------


class TestEvaluate:
    def test_reflected_light_is_s_polarized(self):
        """Unpolarized light off a dielectric (eta 1.5) near Brewster's angle: the reflected light is
        polarized perpendicular to the plane of incidence (s), i.e. along normalize(wo x wi). Checked
        after rotating the output from Mitsuba's basis stokes_basis(wi) to that axis."""
        axes, (_, d, _, _) = grid(n_phi=5, n_d=91, n_h=5)
        m = fresnel.reflection_mueller(np.cos(d), 1.5)
        t = PBRDFTable(*axes, m.astype(np.float32))
        brewster = np.arctan(1.5)
        wo = np.array([np.sin(brewster) * np.cos(0.7), np.sin(brewster) * np.sin(0.7), np.cos(brewster)])
        wi = wo * [-1, -1, 1]  # mirror direction: theta_d = Brewster's angle
        s_out = mueller.apply(evaluate(t, wi, wo, 550.0), [1.0, 0.0, 0.0, 0.0])
        s_axis = np.cross(wo, wi) / np.linalg.norm(np.cross(wo, wi))
        s_in_s_frame = mueller.apply(mueller.rotate_stokes_basis(wi, mueller.stokes_basis(wi), s_axis), s_out)
        assert s_in_s_frame[1] / s_in_s_frame[0] == pytest.approx(1.0, abs=1e-3)  # DoLP 1, s-polarized
        assert s_in_s_frame[2] == pytest.approx(0.0, abs=1e-6)

    def test_batching_and_broadcasting(self, rng):
        t = smooth_random_table(rng)
        wi, wo = random_hemisphere(rng, 12).reshape(3, 4, 3), random_hemisphere(rng, 4)
        lam = np.array([460.0, 555.0, 640.0])[:, None]
        batched = evaluate(t, wi, wo, lam)
        assert batched.shape == (3, 4, 4, 4)
        for i in range(3):
            for j in range(4):
                np.testing.assert_array_equal(batched[i, j], evaluate(t, wi[i, j], wo[j], lam[i, 0]))

    def test_below_horizon_is_zero(self, rng):
        t = smooth_random_table(rng)
        wi = np.array([[0.0, 0.6, 0.8], [0.0, 0.6, -0.8], [1.0, 0.0, 0.0]])
        wo = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
        assert not evaluate(t, wi, wo, 550.0).any()

    def test_mode_swaps_roles(self, rng):
        t = smooth_random_table(rng)
        wi, wo = random_hemisphere(rng, 20), random_hemisphere(rng, 20)
        imp = evaluate(t, wi, wo, 550.0, mode="importance")
        rad = evaluate(t, wo, wi, 550.0)
        np.testing.assert_allclose(imp, rad * (wo[:, 2] / wi[:, 2])[:, None, None], rtol=1e-12, atol=1e-15)
        with pytest.raises(ValueError, match="mode must be 'radiance' or 'importance'"):
            evaluate(t, wi, wo, 550.0, mode="adjoint")

    @pytest.mark.filterwarnings("error")
    def test_numerical_stress(self, rng):
        """Normal incidence, grazing, wi == wo, exact mirror, NaN bins and m00 <= 0: finite, m00 >= 0, no warnings."""
        t = smooth_random_table(rng)
        t.M[:, :, :2] = np.nan  # every bin near theta_h = 0 invalid
        t.M[:, -1, :, :, 0, 0] = -1e-30  # m00 just below 0 at grazing theta_d
        eps = 1e-12
        g = np.sqrt(1 - eps**2)
        n = np.array([0.0, 0.0, 1.0])
        cases = [
            (n, n),  # normal incidence, retro
            (n, [g, 0, eps]),  # grazing light
            ([0, g, eps], [0, -g, eps]),  # both grazing, mirror
            ([0, g, eps], [0, g, eps]),  # grazing retro
            ([0.6, 0, 0.8], [0.6, 0, 0.8]),  # wi == wo
            ([0.6, 0, 0.8], [-0.6, 0, 0.8]),  # exact mirror: h = n
            ([1.0, 0, 0], n),  # exactly at the horizon: zero
            (np.array([0.6, 1e-300, 0.8]), [-0.6, 0, 0.8]),  # nearly mirror, subnormal-scale offsets
        ]
        wi = np.array([c[0] for c in cases], dtype=np.float64)
        wo = np.array([c[1] for c in cases], dtype=np.float64)
        for table in (t, smooth_random_table(rng)):
            m = evaluate(table, wi, wo, np.array([[450.0], [550.0], [650.0], [1e4]]))
            assert np.isfinite(m).all()
            assert (m[..., 0, 0] >= 0).all()
            assert not m[:, 6].any()
        angles = np.stack(rusinkiewicz_from_directions(wi, wo))
        assert np.isfinite(angles).all()


def test_module_exports():
    assert set(tbl.__all__) <= set(dir(tbl))
