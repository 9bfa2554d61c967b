"""Tests of network/model/dense.py: the fast dense-decoding path and the ``stride`` speed/accuracy option.

The fast :func:`~network.model.dense.decode_dense` is checked against
:func:`~network.model.dense.decode_dense_reference` (every masked pixel decoded through the training-mode
:meth:`PixelDecoder.embed`), and ``stride > 1`` against stride 1. Toy and reduced small configurations at small
sizes; the whole file takes a few seconds on CPU.
"""

import math

import pytest
import torch
import torch.nn.functional as F
from torch.nn.attention import SDPBackend, sdpa_kernel
from torch.utils.flop_counter import FlopCounterMode

from network.checkpoint import load_checkpoint
from network.infer import DEFAULT_CHECKPOINT
from network.model.dense import (
    REFINE_BRDF,
    REFINE_DEG,
    box_max,
    context_pixels,
    fill_from_decoded,
    grid_pixels,
    unreliable_fill,
)
from tests.helpers import make_model

pytestmark = pytest.mark.usefixtures("torch_one_thread")  # tests/conftest.py

KEYS = ("normal", "albedo", "roughness", "metallic")


def smooth_maps(size, batch=1):
    """Nine smooth maps (a few periods across the image), (B, 9, size, size)."""
    yy, xx = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    u, v = yy / size, xx / size
    maps = torch.stack([0.3 + 0.2 * torch.sin(3 * u + k) * torch.cos(2 * v - k) for k in range(9)])
    return maps[None].expand(batch, -1, -1, -1).float().contiguous()


def halves_maps(size):
    """:func:`smooth_maps` with a sharp vertical edge off the stride-4 grid: the right part's maps differ."""
    maps = smooth_maps(size)
    maps[..., size // 2 + 1 :] = 0.9 - maps[..., size // 2 + 1 :]
    return maps


def disc_mask(size, fraction=0.5):
    yy, xx = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    r2 = fraction * size * size / math.pi
    return (((yy - size / 2 + 0.5) ** 2 + (xx - size / 2 + 0.5) ** 2) < r2).float()[None, None]


def masked(out, mask):
    """(C, pixels) inside the mask of image 0 for each output."""
    inside = mask[0, 0] > 0
    return {k: out[k][0][:, inside] for k in KEYS}


def assert_valid(out, mask):
    inside = masked(out, mask)
    for key, v in inside.items():
        assert bool(torch.isfinite(v).all()), key
    norms = torch.linalg.vector_norm(inside["normal"], dim=0)
    torch.testing.assert_close(norms, torch.ones_like(norms), rtol=0, atol=1e-5)
    for key in ("albedo", "roughness", "metallic"):
        assert bool(((inside[key] >= 0) & (inside[key] <= 1)).all()), key
    outside = mask[:, 0] == 0
    for key in KEYS:
        assert bool((out[key][: mask.shape[0]].permute(1, 0, 2, 3)[:, outside] == 0).all()), key


class TestExactPath:
    @pytest.mark.parametrize(
        ("name", "size", "overrides"),
        [("toy", 64, {}), ("small", 96, {"train_pixels": 256, "infer_chunk": 1000})],
    )
    def test_dense_equals_reference(self, name, size, overrides):
        model = make_model(name, **overrides)
        g = torch.Generator().manual_seed(2)
        maps = torch.rand(2, 9, size, size, generator=g)
        mask = torch.zeros(2, 1, size, size)
        mask[0] = disc_mask(size, 0.4)[0]
        mask[1, :, 3:9, 5 : size - 4] = 1  # a thin band: more pixels than the toy context
        mask[1, :, 20:21, 2:7] = 1
        with torch.no_grad():
            feats = model.encode(maps, mask)
            fast = model.decode_dense(feats, maps, mask)
            chunked = model.decode_dense(feats, maps, mask, chunk=37)
            ref = model.decode_dense_reference(feats, maps, mask)
        assert int(mask[0].sum()) > model.config.train_pixels  # a real context subset
        for key in KEYS:
            torch.testing.assert_close(fast[key], ref[key], rtol=0, atol=2e-6)
            torch.testing.assert_close(chunked[key], fast[key], rtol=0, atol=2e-6)
        assert_valid(fast, mask[:1])

    def test_empty_and_tiny_masks(self):
        model = make_model()
        maps = torch.rand(3, 9, 64, 64, generator=torch.Generator().manual_seed(3))
        mask = torch.zeros(3, 1, 64, 64)
        mask[1, :, 5:7, 5:9] = 1  # 8 pixels: the context is the whole mask, no query chunks
        mask[2, :, 10:40, 10:40] = 1
        with torch.no_grad():
            feats = model.encode(maps, mask)
            for stride in (1, 3):
                fast = model.decode_dense(feats, maps, mask, stride=stride)
                ref = model.decode_dense_reference(feats, maps, mask)
                assert all(bool((fast[k][0] == 0).all()) for k in KEYS)
                for key in KEYS:
                    torch.testing.assert_close(fast[key][1], ref[key][1], rtol=0, atol=2e-6)

    def test_fewer_flops_than_reference(self):
        # A machine-independent speed check: FlopCounterMode counts the matmuls of both routes (with gradients on:
        # its module tracking fails under no_grad in torch 2.13).
        model = make_model()
        maps = smooth_maps(64)
        feats = model.encode(maps, disc_mask(64)).detach()

        def flops(fn):
            with sdpa_kernel(SDPBackend.MATH), FlopCounterMode(display=False) as counter:
                fn()
            return counter.get_total_flops()

        masks = [disc_mask(64, f) for f in (0.3, 0.4, 0.5)]
        pixels = [int(m.sum()) for m in masks]
        assert min(pixels) > model.config.train_pixels  # a full context: a larger mask only adds query pixels
        fast = [flops(lambda m=m: model.decode_dense(feats, maps, m)) for m in masks]
        # Every extra masked pixel costs the same work (one query against the fixed context, nothing quadratic).
        per_pixel = (fast[1] - fast[0]) / (pixels[1] - pixels[0])
        assert per_pixel > 0
        assert fast[2] - fast[1] == pytest.approx(per_pixel * (pixels[2] - pixels[1]), rel=1e-9)
        reference = flops(lambda: model.decode_dense_reference(feats, maps, masks[2]))
        stride4 = flops(lambda: model.decode_dense(feats, maps, masks[2], stride=4))
        assert fast[2] < 0.9 * reference  # 0.88 for toy (0.85 small, 0.94 paper at 384)
        assert stride4 < 0.25 * fast[2]


class TestStride:
    def test_grid_pixels(self):
        pixels = torch.arange(8 * 10)
        kept = grid_pixels(pixels, 10, 3)
        assert sorted(kept.tolist()) == [r * 10 + c for r in (1, 4, 7) for c in (1, 4, 7)]
        assert torch.equal(grid_pixels(pixels, 10, 1), pixels)

    @pytest.mark.parametrize("k", [1, 3, 5, 7, 15])
    def test_box_max_is_the_window_maximum(self, k):
        # Against a loop over each pixel's window (clipped to the image), with the -max sentinels unreliable_fill
        # puts where nothing was decoded, on a non-square image smaller than the window in one case.
        gen = torch.Generator().manual_seed(k)
        for h, w in ((13, 9), (3, 20)):
            x = torch.randn(2, h, w, generator=gen)
            x[x > 1.2] = -torch.finfo(x.dtype).max
            want = torch.empty_like(x)
            for r in range(h):
                for c in range(w):
                    win = x[:, max(r - k // 2, 0) : r + k // 2 + 1, max(c - k // 2, 0) : c + k // 2 + 1]
                    want[:, r, c] = win.amax(dim=(1, 2))
            assert torch.equal(box_max(x, k), want)

    def test_fill_reproduces_affine_fields(self):
        # Bilinear interpolation is exact for affine fields, and the tent-kernel normalised convolution is bilinear
        # interpolation wherever the four grid pixels around a pixel are decoded.
        h, w, s = 30, 27, 4
        yy, xx = torch.meshgrid(
            torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij"
        )
        field = torch.stack([0.5 + 0.01 * yy - 0.02 * xx, 0.003 * yy * 0 + 0.7 - 0.005 * xx])
        decoded = torch.zeros(h * w, dtype=torch.bool)
        decoded[grid_pixels(torch.arange(h * w), w, s)] = True
        decoded = decoded.reshape(h, w)
        filled, weight = fill_from_decoded(field * decoded, decoded, s)
        lo, hi = s // 2, s // 2 + s * ((h - 1 - s // 2) // s)
        lo_x, hi_x = s // 2, s // 2 + s * ((w - 1 - s // 2) // s)
        interior = (slice(lo, hi + 1), slice(lo_x, hi_x + 1))
        torch.testing.assert_close(filled[(slice(None), *interior)], field[(slice(None), *interior)], atol=1e-5, rtol=0)
        assert bool((weight > 0).all())  # every pixel within s - 1 rows and columns of a grid pixel
        lonely = torch.zeros(h, w, dtype=torch.bool)
        lonely[0, 0] = True
        _, weight = fill_from_decoded(field, lonely, s)
        assert weight[s - 1, s - 1] > 0 and weight[s, 0] == 0 and weight[0, s] == 0

    @pytest.mark.parametrize("stride", [2, 4])
    def test_decoded_pixels_exact_and_rest_close(self, stride):
        model = make_model()
        maps, mask = smooth_maps(64), disc_mask(64, 0.6)
        with torch.no_grad():
            feats = model.encode(maps, mask)
            full = model.decode_dense(feats, maps, mask)
            fast = model.decode_dense(feats, maps, mask, stride=stride)
        assert_valid(fast, mask)
        idx = torch.nonzero(mask.reshape(-1) > 0).squeeze(1)
        exact = torch.cat([grid_pixels(idx, 64, stride), context_pixels(idx, model.config.train_pixels)])
        for key in KEYS:
            a, b = full[key].reshape(full[key].shape[1], -1), fast[key].reshape(fast[key].shape[1], -1)
            torch.testing.assert_close(b[:, exact], a[:, exact], rtol=0, atol=1e-6)
        # Elsewhere: interpolation of a smooth prediction, so its error is a small fraction of the error of the
        # best constant (the mean over the mask). Measured: 0.03-0.05 at stride 2, 0.13-0.15 at stride 4.
        ref, got = masked(full, mask), masked(fast, mask)
        mean_normal = F.normalize(ref["normal"].mean(1, keepdim=True), dim=0)
        angle = torch.rad2deg(torch.acos((ref["normal"] * got["normal"]).sum(0).clamp(-1, 1)))
        spread = torch.rad2deg(torch.acos((ref["normal"] * mean_normal).sum(0).clamp(-1, 1)))
        assert float(angle.mean()) < 0.25 * float(spread.mean())
        for key in ("albedo", "roughness", "metallic"):
            err = (ref[key] - got[key]).abs().mean()
            assert float(err) < 0.25 * float((ref[key] - ref[key].mean(1, keepdim=True)).abs().mean()), key

    def test_refined_pixels_exact(self):
        # Edge-aware stride: the filled pixels that unreliable_fill flags get exactly their stride-1 values, the
        # others keep the plain interpolation.
        model = make_model()
        maps, mask = halves_maps(64), disc_mask(64, 0.6)
        with torch.no_grad():
            feats = model.encode(maps, mask)
            full = model.decode_dense(feats, maps, mask)
            plain = model.decode_dense(feats, maps, mask, stride=4, refine_deg=None)
            fast = model.decode_dense(feats, maps, mask, stride=4, refine_deg=REFINE_DEG)
        assert_valid(fast, mask)
        idx = torch.nonzero(mask.reshape(-1) > 0).squeeze(1)
        decoded = torch.zeros(64, 64, dtype=torch.bool)
        decoded.view(-1)[grid_pixels(idx, 64, 4)] = True
        decoded.view(-1)[context_pixels(idx, model.config.train_pixels)] = True
        values = torch.cat([fast[k][0] for k in KEYS])
        _, weight = fill_from_decoded(values, decoded, 4)
        bad = unreliable_fill(values, decoded, weight, 4, REFINE_DEG, REFINE_BRDF)
        filled = (mask[0, 0] > 0) & ~decoded & (weight > 0)
        refined, kept = filled & bad, filled & ~bad
        assert 0 < int(refined.sum()) < int(filled.sum())
        for key in KEYS:
            torch.testing.assert_close(fast[key][0][:, refined], full[key][0][:, refined], rtol=0, atol=1e-6)
            assert torch.equal(fast[key][0][:, kept], plain[key][0][:, kept]), key
            assert torch.equal(fast[key][0][:, decoded], plain[key][0][:, decoded]), key

    def test_refinement_bounds_edge_error(self):
        # Two halves with different maps: a sharp edge that plain stride-4 interpolation blurs (p99 error above
        # the threshold) and the edge-aware one decodes (p99 below it).
        model = make_model()
        maps, mask = halves_maps(64), torch.ones(1, 1, 64, 64)
        with torch.no_grad():
            feats = model.encode(maps, mask)
            full = model.decode_dense(feats, maps, mask)
            plain = model.decode_dense(feats, maps, mask, stride=4, refine_deg=None)
            fast = model.decode_dense(feats, maps, mask, stride=4, refine_deg=2.0)

        def p99(out):
            cos = (out["normal"] * full["normal"]).sum(1).clamp(-1, 1)
            return float(torch.quantile(torch.rad2deg(torch.acos(cos)).reshape(-1), 0.99))

        assert p99(plain) > 2.0
        assert p99(fast) < 2.0

    @staticmethod
    def _sphere_and_crease(h=128, w=128, s=4, radius=48.0):
        """Analytic normal fields on a grid decoded every ``s`` pixels: a sphere of radius 48 px seen from its pole
        (up to 72 deg from the view; neighbouring grid pixels 5-15 deg apart), decoded inside 0.95 of its radius,
        and a crease (two flat halves 20 deg apart along a line between grid columns); constant BRDF channels."""
        r = torch.arange(h, dtype=torch.float64)
        yy, xx = torch.meshgrid(r, torch.arange(w, dtype=torch.float64), indexing="ij")
        u, v = (xx - w / 2) / radius, (yy - h / 2) / radius
        inside = u**2 + v**2 < 0.95**2
        sphere = torch.stack([u, v, torch.sqrt((1 - u**2 - v**2).clamp_min(0))])
        t = math.radians(10.0)
        crease = torch.where(xx < w / 2 + 0.5, 1.0, -1.0) * math.sin(t)
        crease = torch.stack([crease, torch.zeros_like(xx), torch.full_like(xx, math.cos(t))])
        brdf = torch.full((5, h, w), 0.3, dtype=torch.float64)
        grid = torch.zeros(h * w, dtype=torch.bool)
        grid[grid_pixels(torch.arange(h * w), w, s)] = True
        grid = grid.reshape(h, w)
        return [(torch.cat([sphere, brdf]).float(), grid & inside), (torch.cat([crease, brdf]).float(), grid)]

    def test_refinement_spares_smooth_curvature_and_catches_creases(self):
        # Linear interpolation of a uniformly curved field is accurate to a fraction of a degree, so the
        # curvature test clears most of what the range test alone would decode; a crease between grid pixels stays.
        s = 4
        chord = 2 * math.sin(math.radians(REFINE_DEG) / 2)
        for (field, decoded), smooth in zip(self._sphere_and_crease(s=s), (True, False), strict=True):
            filled, weight = fill_from_decoded(field, decoded, s)
            bad = unreliable_fill(field, decoded, weight, s, REFINE_DEG, REFINE_BRDF)
            todo = ~decoded & (weight >= 1 - 0.5 / s**2)  # full stencils
            n_fill = F.normalize(filled[:3], dim=0)
            err = torch.rad2deg(torch.acos((n_fill * F.normalize(field[:3], dim=0)).sum(0).clamp(-1, 1)))
            kept = todo & ~bad
            if smooth:
                # The range test alone flags nearly all of the sphere (neighbours more than 4 deg apart).
                hi = torch.where(decoded, field, -1e30)[None]
                lo = torch.where(decoded, -field, -1e30)[None]
                span = (F.max_pool2d(hi, 2 * s - 1, 1, s - 1) + F.max_pool2d(lo, 2 * s - 1, 1, s - 1))[0]
                range_flags = todo & (span[:3].square().sum(0) > chord**2)
                assert int(range_flags.sum()) > 0.9 * int(todo.sum())
                assert int((todo & bad).sum()) < 0.5 * int(todo.sum())  # measured 38 %, the rim
                assert float(err[kept].max()) < 0.5  # measured 0.14 deg
            else:
                c = field.shape[-1] // 2  # the crease lies between columns c and c + 1, inside the cell c - 1 .. c + 1
                assert bool(bad[:, c - 1 : c + 2][todo[:, c - 1 : c + 2]].all())  # every fill of that cell
                assert float(err[kept].max()) < 1e-3  # the rest lies on the flat halves

    def test_thin_parts_are_decoded(self):
        # Pixels with no decoded pixel within stride - 1 rows and columns are decoded, not left at zero.
        model = make_model()
        maps = smooth_maps(64)
        mask = torch.zeros(1, 1, 64, 64)
        mask[..., 30:60, 30:60] = 1
        mask[..., 0, 0:20] = 1  # a one-pixel line on row 0, off the stride-4 grid (rows 2, 6, ...)
        mask[..., 5:15, 60] = 1  # and a column on 60 (grid columns 58, 62)
        with torch.no_grad():
            feats = model.encode(maps, mask)
            full = model.decode_dense(feats, maps, mask)
            fast = model.decode_dense(feats, maps, mask, stride=4)
        assert_valid(fast, mask)
        idx = torch.nonzero(mask.reshape(-1) > 0).squeeze(1)
        decoded = torch.zeros(64 * 64, dtype=torch.bool)
        decoded[grid_pixels(idx, 64, 4)] = True
        decoded[context_pixels(idx, model.config.train_pixels)] = True
        _, weight = fill_from_decoded(torch.zeros(1, 64, 64), decoded.reshape(64, 64), 4)
        lonely = (mask.reshape(-1) > 0) & (weight.reshape(-1) == 0)
        assert int(lonely.sum()) > 0
        for key in KEYS:
            a, b = full[key].reshape(full[key].shape[1], -1), fast[key].reshape(fast[key].shape[1], -1)
            torch.testing.assert_close(b[:, lonely], a[:, lonely], rtol=0, atol=1e-6)

    @pytest.mark.parametrize("stride", [2, 4])
    def test_chunks_on_worker_threads_equal_one_thread(self, stride, monkeypatch):
        # Two torch threads: the chunks go to two Python threads of one torch thread each (query_workers); the
        # outputs are those of the calling thread's route, torch's thread count is restored, and the threads ran.
        import threading

        from network.model import dense

        model = make_model()
        maps, mask = smooth_maps(64), disc_mask(64, 0.6)
        names = set()
        heads = model.decoder.heads

        def spy(x):
            names.add(threading.current_thread().name)
            return heads(x)

        with torch.inference_mode():
            feats = model.encode(maps, mask)
            torch.set_num_threads(2)
            monkeypatch.setattr(dense, "_PARALLEL_QUERIES", False)
            serial = model.decode_dense(feats, maps, mask, chunk=64, stride=stride)
            monkeypatch.setattr(dense, "_PARALLEL_QUERIES", True)
            monkeypatch.setattr(model.decoder, "heads", spy)
            parallel = model.decode_dense(feats, maps, mask, chunk=64, stride=stride)
            with torch.autocast("cpu", dtype=torch.bfloat16):  # the caller's autocast reaches the worker threads
                cast = model.decode_dense(feats, maps, mask, chunk=64, stride=stride)
                monkeypatch.setattr(dense, "_PARALLEL_QUERIES", False)
                cast_serial = model.decode_dense(feats, maps, mask, chunk=64, stride=stride)
        assert torch.get_num_threads() == 2
        assert sum(name.startswith("decode") for name in names) == 2, names
        for key in KEYS:
            torch.testing.assert_close(parallel[key], serial[key], rtol=0, atol=1e-5)
            torch.testing.assert_close(cast[key], cast_serial[key], rtol=0, atol=1e-5)
        assert_valid(parallel, mask)

    def test_bad_stride(self):
        model = make_model()
        maps, mask = smooth_maps(64), disc_mask(64)
        for bad in (0, -2, 1.5, True):
            with pytest.raises(ValueError, match="stride must be a positive int"):
                model(maps, mask, stride=bad)


class TestContextPixels:
    def test_context_pixels(self):
        idx = torch.arange(100, 200)
        assert torch.equal(context_pixels(idx, 200), idx)
        sub = context_pixels(idx, 10)
        assert sub.tolist() == list(range(100, 200, 10))


class TestShippedCheckpoint:
    @pytest.mark.skipif(not DEFAULT_CHECKPOINT.is_file(), reason="models/small/model.pt not trained in this tree")
    def test_shipped_checkpoint_fast_path_equals_reference(self):
        model, _ = load_checkpoint(DEFAULT_CHECKPOINT)
        size = model.config.image_size  # 128 for the shipped model: the mask must lie inside it
        g = torch.Generator().manual_seed(7)
        maps = torch.rand(2, 9, size, size, generator=g)  # two different inputs
        mask = torch.zeros(2, 1, size, size)
        mask[..., 20:90, 30:100] = 1  # 4900 pixels: a context subset and a few chunks, still fast
        assert int(mask[0].sum()) == 4900 > model.config.train_pixels
        with torch.no_grad():
            feats = model.encode(maps, mask)
            fast = model.decode_dense(feats, maps, mask)
            ref = model.decode_dense_reference(feats, maps, mask)
        inside = mask[0, 0] > 0
        for key in KEYS:
            a, b = fast[key][0][:, inside], fast[key][1][:, inside]
            # Real predictions, not the zeros outside the mask: nonzero and depending on the input.
            assert float(a.abs().mean()) > 1e-3 and float(b.abs().mean()) > 1e-3, key
            assert float((a - b).abs().max()) > 1e-3, key
        assert_valid(fast, mask)
        for key in KEYS:
            torch.testing.assert_close(fast[key], ref[key], rtol=0, atol=1e-5)
