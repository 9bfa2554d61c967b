"""Test-time refinement: correct the network's albedo scale so that the re-rendered unpol matches the capture.

Analysis by synthesis with a low-dimensional correction (issue 27, item 2). The network's maps
(:func:`network.infer.predict`) on a plane at the capture's distance are re-rendered under the display
(:func:`network.rerender.rerender`, the ``"fresnel"`` diffuse lobe of the renderer's ``pplastic``);
per object (a connected component of the mask) one albedo scale ``s`` is fitted on its dielectric
pixels so that the re-rendered unpol ``s D + S`` (``D`` the diffuse, ``S`` the specular leakage
into unpol) matches the decoded unpol ``o``:

.. math::
    s = \\arg\\min_s \\sum_p w_p\\, \\rho\\big((o_p - s D_p - S_p) / (o_p + s D_p + S_p)\\big)

with a Cauchy loss ``rho``, minimised by a 1-D search over ``log s`` (coarse, then fine).
The scale is the only thing the network cannot know (a dark object near the display looks like a
bright one far from it); the chroma and the texture stay the network's. The confidence ``w_p``
keeps out what the re-renderer cannot explain: grazing normals (``n . v`` small), dark and
saturated pixels, pixels brighter in LP than in unpol (metal-like), and, through the robust loss,
cast shadows and interreflections. The scale is searched within :data:`SCALE_RANGE` only; an
object with too few confident pixels keeps the network's albedo, and so does every object when
the fit does not lower the re-rendering loss, and the result says so. Per object, the guard
(:mod:`network.refine_guard`) keeps the network's albedo where the decoded LP is not the lobe the
re-renderer predicts (a measured material, a metal, a shadow) or the fitted scale darkens it below
the guard's floor, and applies ``s ** shrink`` (the MAP with the network's albedo as a log-normal
prior) elsewhere; it also says which objects' roughness may be refined.

The scale needs calibrated radiometry (the display radiance in the maps' units) and the object's
distance; without the radiance nothing is refined, without the distance the rig's default is used
(the scale is then only as good as that guess).

Cost: one re-rendering of at most :data:`MAX_PIXELS` sampled pixels under a coarse patch grid
(:data:`PATCHES`; the diffuse lobe is smooth), seconds on two CPU cores (measured:
docs/measurements/refine.md).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import torch

from pbrdf.data.capture_meta import DEFAULT_DISTANCE_M

from . import refine_guard
from .refine_guard import GuardParams
from .rerender import display_patches, points_from_depth, rerender

__all__ = ["MAX_PIXELS", "PATCHES", "REFINE_ROUGHNESS", "SCALE_RANGE", "RefineResult", "albedo_from_terms",
           "albedo_terms", "guard_objects", "object_scales", "refine", "refine_input", "scaled_loss"]  # fmt: skip

#: Pixels re-rendered per capture (sampled evenly over the objects; the scale needs no more).
MAX_PIXELS = 2048
#: Display patches per colour region for the refinement's re-rendering.
PATCHES = (8, 8)
#: Fitted scales outside this range are not trusted (the network's albedo is kept).
SCALE_RANGE = (0.25, 4.0)
#: Fewest confident pixels an object needs for its scale.
MIN_PIXELS = 24
#: Whether ``--refine`` (:func:`refine_input`, ``evaluate.py --refine``) also refines the roughness
#: (:mod:`network.refine_roughness`): off, the test splits' per-scene means say it helps single plastic
#: objects and hurts table pBRDFs (docs/measurements/roughness.md).
REFINE_ROUGHNESS = False
_COS_MIN = 0.3  # n . v below this: grazing, the re-renderer's geometry is least reliable
_CAUCHY = 0.15  # relative residual at which the Cauchy loss halves a pixel's weight


@dataclass
class RefineResult:
    """What :func:`refine` did.

    Attributes:
        pred: the maps (the network's ``pred`` with the refined albedo, or the network's own).
        refined: whether any albedo was changed.
        loss_before: robust re-rendering loss of the network's maps (None when nothing was fitted).
        loss_after: the same after the refinement.
        scales: per object (component id -> scale, 1.0 where kept).
        seconds: wall time.
        message: one line for the user.
        roughness: per object, what the roughness refinement did (:class:`network.refine_roughness.RoughnessResult`'s
            ``objects``; empty when it did not run).
        guard: per object, the guard's cue and verdict (:func:`guard_objects`).
    """

    pred: dict[str, np.ndarray]
    refined: bool
    loss_before: float | None
    loss_after: float | None
    scales: dict[int, float] = field(default_factory=dict)
    seconds: float = 0.0
    message: str = ""
    roughness: dict[int, dict] = field(default_factory=dict)
    guard: dict[int, dict] = field(default_factory=dict)


def _cauchy(r: np.ndarray) -> np.ndarray:
    return np.log1p((r / _CAUCHY) ** 2)


def object_scales(
    obs: np.ndarray, diffuse: np.ndarray, leak: np.ndarray, weight: np.ndarray, labels: np.ndarray
) -> tuple[dict[int, float], float, float]:
    """Per-label robust scale ``s`` of ``diffuse`` so that ``s diffuse + leak`` matches ``obs``.

    Args:
        obs: ``(P, 3)`` observed unpol.
        diffuse: ``(P, 3)`` re-rendered diffuse part (linear in the albedo).
        leak: ``(P, 3)`` re-rendered specular part in unpol (not scaled).
        weight: ``(P,)`` confidence >= 0.
        labels: ``(P,)`` object label per pixel.

    Returns:
        ``(scales, loss_before, loss_after)``: a scale per label with enough confident pixels and a
        plausible value (others absent), and the weighted mean Cauchy loss at ``s = 1`` and at the scales.

    Example:
        >>> d = np.full((40, 3), 0.2)
        >>> s, before, after = object_scales(1.5 * d, d, 0 * d, np.ones(40), np.zeros(40, int))
        >>> round(s[0], 3), after < before
        (1.5, True)
    """
    scale = np.ones(obs.shape[0])
    out: dict[int, float] = {}
    # A direct 1-D search on log s (coarse, then fine): the loss is not convex in s, the range is small.
    coarse = np.exp(np.linspace(np.log(SCALE_RANGE[0]), np.log(SCALE_RANGE[1]), 57))
    for lab in np.unique(labels):
        sel = (labels == lab) & (weight > 0)
        if sel.sum() < MIN_PIXELS:
            continue
        o, d, k, w = obs[sel], diffuse[sel], leak[sel], weight[sel][:, None]

        def object_loss(s: np.ndarray, o=o, d=d, k=k, w=w) -> np.ndarray:
            fit = s[:, None, None] * d + k
            return np.sum(w * _cauchy((o - fit) / (np.abs(o) + np.abs(fit) + 1e-6)), axis=(1, 2))

        best = float(coarse[np.argmin(object_loss(coarse))])
        fine = np.append(best * np.exp(np.linspace(-0.05, 0.05, 21)), 1.0)
        s = float(fine[np.argmin(object_loss(fine))])
        if np.isfinite(s) and SCALE_RANGE[0] <= s <= SCALE_RANGE[1]:
            out[int(lab)] = s
            scale[labels == lab] = s

    return (
        out,
        scaled_loss(obs, diffuse, leak, weight, np.ones_like(scale)),
        scaled_loss(obs, diffuse, leak, weight, scale),
    )


def scaled_loss(obs: np.ndarray, diffuse: np.ndarray, leak: np.ndarray, weight: np.ndarray, scale: np.ndarray) -> float:
    """Weighted mean Cauchy loss of the relative unpol residual with per-pixel scales ``scale`` ``(P,)``."""
    fit = scale[:, None] * diffuse + leak
    r = (obs - fit) / (np.abs(obs) + np.abs(fit) + 1e-6)
    return float(np.sum(weight[:, None] * _cauchy(r)) / max(3 * float(weight.sum()), 1e-12))


def _confidence(maps: np.ndarray, pred: dict[str, np.ndarray], view_cos: np.ndarray) -> np.ndarray:
    """``(P,)`` weights in [0, 1]: dielectric, facing the camera, neither dark nor saturated, unpol above LP."""
    unpol, lp = maps[:, :3].sum(1), maps[:, 3:6].sum(1)
    lit = unpol > 0.02 * max(float(np.percentile(unpol, 99)), 1e-12)
    unsaturated = unpol < 0.98 * max(float(unpol.max()), 1e-12)
    w = np.clip((view_cos - _COS_MIN) / (1.0 - _COS_MIN), 0.0, 1.0)
    w *= (pred["metallic"][:, 0] < 0.5) & lit & unsaturated & (lp < unpol)
    return w


def _sample(mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Flat indices of at most :data:`MAX_PIXELS` mask pixels (uniform: every object in proportion)."""
    idx = np.flatnonzero(mask)
    if idx.size <= MAX_PIXELS:
        return idx
    return np.sort(rng.choice(idx, MAX_PIXELS, replace=False))


def refine(
    pred: dict[str, np.ndarray],
    maps: np.ndarray,
    intrinsics: np.ndarray,
    rig,
    radiance: float | None,
    distance_m: float | None = None,
    *,
    seed: int = 0,
    roughness: bool = False,
    guard: GuardParams | None = None,
) -> RefineResult:
    """Refine the network's albedo scale per object against the decoded unpol (module docs), and its roughness.

    With ``roughness``, each object's roughness is then refined from the decoded LP
    (:func:`network.refine_roughness.refine_roughness`, which needs no radiance: the LP's level is free).

    Args:
        pred: :func:`network.infer.predict`'s maps ``(H, W, C)`` with ``mask``.
        maps: ``(H, W, 9)`` the nine decoded maps the network saw.
        intrinsics: ``K (3, 3)`` of the maps' grid.
        rig: the capture's :class:`pbrdf.sensor.rig.Rig` (display geometry and radiance).
        radiance: the display radiance in the maps' units, or None (uncalibrated: nothing refined).
        distance_m: the object's distance in m (default :data:`pbrdf.data.capture_meta.DEFAULT_DISTANCE_M`).
        seed: pixel sampling seed.
        roughness: also refine the roughness per object.
        guard: when the re-renderer is not trusted (default :data:`network.refine_guard.GUARD`).

    Returns:
        :class:`RefineResult`; its maps are finite, the albedo in [0, 1].
    """
    res = _refine_albedo(pred, maps, intrinsics, rig, radiance, distance_m, seed=seed, guard=guard)
    if not roughness:
        return res
    from .refine_roughness import refine_roughness  # noqa: PLC0415

    if not res.guard:  # uncalibrated or empty: the LP's level, the guard's cue, is unknown
        res.message += "; roughness kept: the guard needs the display radiance"
        return res
    skip = {k: g["roughness"] for k, g in res.guard.items() if g.get("roughness")}
    rough = refine_roughness(res.pred, maps, intrinsics, rig, float(distance_m or DEFAULT_DISTANCE_M), seed=seed,
                             skip=skip)  # fmt: skip
    res.pred, res.roughness = rough.pred, rough.objects
    res.refined = res.refined or rough.refined
    res.seconds += rough.seconds
    res.message = f"{res.message}; {rough.message}"
    return res


def albedo_terms(
    pred: dict[str, np.ndarray],
    maps: np.ndarray,
    intrinsics: np.ndarray,
    rig,
    radiance: float,
    distance_m: float | None,
    *,
    seed: int = 0,
) -> dict[str, np.ndarray]:
    """What the albedo fit and its guard see at the sampled pixels (one re-rendering of the network's maps).

    Args:
        pred: :func:`network.infer.predict`'s maps ``(H, W, C)`` with ``mask``.
        maps: ``(H, W, 9)`` the decoded maps.
        intrinsics: ``K (3, 3)``.
        rig: the capture's rig.
        radiance: the display radiance in the maps' units (> 0).
        distance_m: the object's distance in m (None: the default).
        seed: pixel sampling seed.

    Returns:
        ``idx`` ``(P,)`` flat pixel indices, ``labels`` ``(H, W)`` components of the mask, ``lab`` ``(P,)``,
        ``obs`` ``(P, 9)`` decoded maps in the display's radiance units, ``diffuse`` and ``leak`` ``(P, 3)``
        (the unpol is ``s diffuse + leak`` for an albedo scale ``s``), ``lp`` ``(P, 3)`` the re-rendered LP,
        ``weight`` ``(P,)`` the confidence.
    """
    from scipy import ndimage  # noqa: PLC0415

    mask = pred["mask"][..., 0] > 0
    labels, _ = ndimage.label(mask)
    idx = _sample(mask, np.random.default_rng(seed))
    h, w = mask.shape
    # A plane at the capture's distance: the diffuse lobe sees the light directions and the 1/d^2
    # falloff at the object, which a relief would change by its depth over the distance only.
    plane = torch.full((1, 1, h, w), float(distance_m if distance_m else DEFAULT_DISTANCE_M))
    pts = points_from_depth(plane, intrinsics).reshape(1, 3, h * w)[:, :, idx]

    def flat(name: str) -> np.ndarray:
        return pred[name].reshape(h * w, -1)[idx].astype(np.float32)

    p = {k: flat(k) for k in ("normal", "albedo", "roughness", "metallic")}
    t = {k: torch.from_numpy(v.T.copy())[None] for k, v in p.items()}
    patches = display_patches(rig, PATCHES)
    with torch.no_grad():
        unit = rerender(t["normal"], torch.ones_like(t["albedo"]), t["roughness"], t["metallic"], pts, patches,
                        diffuse="fresnel", chunk=1024)  # fmt: skip
    # The specular lobe's share in unpol, (1 - g) / g of its LP for the display's mean LP gain g
    # (1 for the default, fully polarized display: no leak); one re-rendering instead of two.
    g = float(patches.lp_gain.mean())
    lp = unit["lp"][0].T.double().numpy()
    leak = lp * ((1.0 - g) / g if g > 0.05 else 0.0)
    diffuse = (unit["unpol"][0].T.double().numpy() - leak).clip(min=0.0) * p["albedo"]
    obs = np.nan_to_num(maps.reshape(h * w, -1)[idx].astype(np.float64) * (float(rig.display.radiance) / radiance))
    view = -pts[0].T.numpy().astype(np.float64)
    view_cos = np.sum(p["normal"] * view, 1) / np.maximum(np.linalg.norm(view, axis=1), 1e-12)
    return {"idx": idx, "labels": labels, "lab": labels.reshape(-1)[idx], "obs": obs, "diffuse": diffuse,
            "leak": leak, "lp": lp, "weight": _confidence(obs, p, view_cos)}  # fmt: skip


def guard_objects(terms: dict[str, np.ndarray], params: GuardParams | None = None) -> dict[int, dict]:
    """Per component: its LP gain and share (:mod:`network.refine_guard`) and why its roughness is not refined.

    Args:
        terms: :func:`albedo_terms`.
        params: the guard (default :data:`network.refine_guard.GUARD`).

    Returns:
        component id -> ``{"lp_gain", "lp_share", "roughness"}`` (``roughness``: the reason, or None) for
        components with confident pixels; every other component gets ``{"roughness": reason}``.
    """
    params = params or refine_guard.GUARD
    out = {}
    for lab in np.unique(terms["lab"][terms["weight"] > 0]).tolist():
        sel = (terms["lab"] == lab) & (terms["weight"] > 0)
        w = terms["weight"][sel]
        gain = refine_guard.lp_gain(terms["obs"][sel, 3:6], terms["lp"][sel], w)
        model_unpol = float(np.sum(w[:, None] * (terms["diffuse"][sel] + terms["leak"][sel])))
        share = float(np.sum(w[:, None] * terms["lp"][sel])) / max(model_unpol, 1e-30)
        out[int(lab)] = {
            "lp_gain": gain if np.isfinite(gain) else None,  # None: strict JSON in the evaluation rows
            "lp_share": share,
            "albedo": refine_guard.lp_untrusted(gain, share, params, params.albedo_lp_gain),
            "roughness": refine_guard.lp_untrusted(gain, share, params),
        }
    for lab in range(1, int(terms["labels"].max()) + 1):
        out.setdefault(lab, {"roughness": "no confident pixels to check its LP against the re-renderer"})
    return out


def _refine_albedo(
    pred: dict[str, np.ndarray],
    maps: np.ndarray,
    intrinsics: np.ndarray,
    rig,
    radiance: float | None,
    distance_m: float | None,
    *,
    seed: int,
    guard: GuardParams | None = None,
) -> RefineResult:
    """The albedo half of :func:`refine`."""
    start = time.perf_counter()
    mask = pred["mask"][..., 0] > 0

    def keep(message: str) -> RefineResult:
        return RefineResult(pred, False, None, None, {}, time.perf_counter() - start, message)

    if radiance is None or not radiance > 0:
        return keep("not refined: the capture's radiometry is relative (no display radiance)")
    if not mask.any():
        return keep("not refined: the mask is empty")
    t = albedo_terms(pred, maps, intrinsics, rig, radiance, distance_m, seed=seed)
    res = albedo_from_terms(pred, t, guard or refine_guard.GUARD)
    res.seconds = time.perf_counter() - start
    return res


def albedo_from_terms(
    pred: dict[str, np.ndarray], t: dict[str, np.ndarray], params: GuardParams | None = None
) -> RefineResult:
    """The guarded per-object albedo scales from :func:`albedo_terms` and the refined maps.

    Args:
        pred: the network's maps.
        t: :func:`albedo_terms` of ``pred``.
        params: the guard (default :data:`network.refine_guard.GUARD`).

    Returns:
        :class:`RefineResult` (``seconds`` 0).
    """
    mask = pred["mask"][..., 0] > 0
    params = params or refine_guard.GUARD
    guard = guard_objects(t, params)
    labels = t["labels"]
    fitted, before, _ = object_scales(t["obs"][:, :3], t["diffuse"], t["leak"], t["weight"], t["lab"])
    scales = {}
    for lab, s in fitted.items():
        g = guard.setdefault(lab, {})
        g["fitted"] = s
        g["albedo"] = g.get("albedo") or refine_guard.scale_untrusted(s, params)
        if g["albedo"] is None:
            scales[lab] = float(s**params.shrink)
    per_pixel = np.array([scales.get(int(k), 1.0) for k in t["lab"]])
    after = scaled_loss(t["obs"][:, :3], t["diffuse"], t["leak"], t["weight"], per_pixel)
    if not scales:
        return RefineResult(pred, False, before, before, {}, 0.0, "not refined: no object with enough confident "
                            "dielectric pixels the re-renderer explains", guard=guard)  # fmt: skip
    if not after < before:
        return RefineResult(pred, False, before, before, {}, 0.0, f"not refined: the fit did not lower the "
                            f"re-rendering loss ({before:.4f} -> {after:.4f})", guard=guard)  # fmt: skip
    gain = np.ones(mask.shape, np.float32)
    for lab, s in scales.items():
        gain[labels == lab] = s
    dielectric = pred["metallic"][..., 0] < 0.5
    albedo = np.where(dielectric[..., None], np.clip(pred["albedo"] * gain[..., None], 0.0, 1.0), pred["albedo"])
    out = {**pred, "albedo": np.where(mask[..., None], albedo, 0.0).astype(np.float32)}
    shown = ", ".join(f"{s:.2f}" for s in scales.values())
    return RefineResult(out, True, before, after, scales, 0.0,
                        f"refined the albedo scale of {len(scales)} object(s) ({shown}); re-rendering loss "
                        f"{before:.4f} -> {after:.4f}", guard=guard)  # fmt: skip


def refine_input(pred: dict[str, np.ndarray], inp, *, warn: bool = True) -> RefineResult:
    """:func:`refine` for a :class:`network.infer.InferenceInput`; warns when nothing changed or no distance was given.

    Args:
        pred: :func:`network.infer.predict`'s maps for ``inp``.
        inp: the input (its maps, intrinsics, rig, radiance and ``distance_m``).
        warn: warn as above; False leaves the telling to the caller (``infer.py``'s default refinement, where the
            guard keeping the network's maps is a normal outcome: ``res.message`` says it).

    Returns:
        The :class:`RefineResult` (its ``pred`` is what to write).
    """
    from pbrdf.sensor.rig import Rig  # noqa: PLC0415

    res = refine(pred, inp.maps, inp.intrinsics, inp.rig or Rig(), inp.radiance, inp.distance_m,
                 roughness=REFINE_ROUGHNESS)  # fmt: skip
    if not warn:
        return res
    if not res.refined:
        warnings.warn(f"refinement: {res.message}; the network's maps are kept", stacklevel=2)
    elif res.message.startswith("not refined"):  # the roughness changed, the albedo did not
        warnings.warn(f"refinement: {res.message}; the network's albedo is kept", stacklevel=2)
    elif not inp.distance_m:
        warnings.warn(f"refinement at the default distance {DEFAULT_DISTANCE_M} m (no distance_m given): the albedo "
                      "scale is only as good as that guess", stacklevel=2)  # fmt: skip
    return res
