"""The demo's per-scene figures (inputs, results, relit frames) and captions that say how to read them.

Conventions every figure here follows, repeated in its caption:

* radiometric maps (unpol, LP) are tone-mapped per image by :func:`tone_map`: divided by the
  99.5th percentile of the object's pixels (all three channels) and shown with gamma 2.2; the
  white point is printed in the panel title, so two panels compare by their white points. A plain
  linear stretch shows a metal (whose unpolarized part is small) as black but for a highlight;
* the CP map (``s3 / s0``, signed) is drawn on a diverging scale symmetric about 0 with a colour bar;
* normals are drawn as ``(n + 1) / 2``: x (right) -> red, y (up) -> green, z (toward the
  camera) -> blue, with a key (:func:`normal_key`) beside them;
* pixels off the object are grey in scalar panels, black in RGB panels.

Example:
    >>> key = normal_key(33)
    >>> [round(float(v), 2) for v in key[16, 32]], [round(float(v), 2) for v in key[16, 16]]  # right edge, centre
    ([1.0, 0.5, 0.5], [0.5, 0.5, 1.0])
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from network.demo import report
from network.metrics import normal_angle_deg

__all__ = ["tone_map", "normal_key", "angle_map", "scene_figures", "relit_figure", "NORMAL_KEY_TITLE"]

#: Percentile of the object's pixels that :func:`tone_map` maps to white.
WHITE_PERCENTILE = 99.5
#: Display gamma of :func:`tone_map`.
GAMMA = 2.2
#: Colour of the pixels off the object in scalar panels.
NAN_COLOUR = "0.82"
#: Title of the normal-colour key panel.
NORMAL_KEY_TITLE = "normal key: x→red, y→green, z→blue"


def tone_map(img: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, float]:
    """Per-image preview of a radiometric ``(H, W, 3)`` map: ``clip(img / white, 0, 1) ** (1 / 2.2)`` on ``mask``.

    ``white`` is the :data:`WHITE_PERCENTILE` percentile of the masked values (all channels);
    the gamma lifts the weak structure that a linear stretch leaves black.

    Returns:
        The RGB image in [0, 1] (0 off ``mask``) and ``white``.
    """
    vals = img[mask]
    white = max(float(np.percentile(vals, WHITE_PERCENTILE)) if vals.size else 1.0, 1e-8)
    return np.clip(img / white, 0, 1) ** (1 / GAMMA) * mask[..., None], white


def normal_key(size: int = 65) -> np.ndarray:
    """The normal colours of a hemisphere facing the camera, ``(size, size, 3)``: the key to every normal panel.

    Each pixel shows the normal of a unit hemisphere seen along ``-z`` with the mapping of the
    normal panels, ``(n + 1) / 2``; outside the disk it is white.
    """
    yy, xx = np.mgrid[0:size, 0:size]
    x = (xx - (size - 1) / 2) / ((size - 1) / 2)
    y = ((size - 1) / 2 - yy) / ((size - 1) / 2)
    r2 = x**2 + y**2
    n = np.stack([x, y, np.sqrt(np.clip(1 - r2, 0, 1))], axis=-1)
    return np.where((r2 <= 1)[..., None], n * 0.5 + 0.5, 1.0).astype(np.float32)


def angle_map(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Angle in degrees between ``(H, W, 3)`` vector maps, NaN outside ``mask``."""
    return np.where(mask, normal_angle_deg(a, b), np.nan)


def _signed_limit(values: np.ndarray) -> float:
    """Half-range of a diverging scale: the 99th percentile of ``|values|``, at least 1e-3."""
    return max(float(np.percentile(np.abs(values), 99.0)) if values.size else 0.0, 1e-3)


def scene_figures(fig_dir: Path, name: str, maps, mask, gt, pred, base) -> list[tuple[str, str]]:
    """Input and result figures of one scene; returns ``(path relative to fig_dir's parent, caption)``.

    Args:
        fig_dir: folder of the PNGs.
        name: scene name (file prefix and caption prefix).
        maps: ``(H, W, 9)`` decoded nine maps.
        mask: ``(H, W)`` object coverage.
        gt: ground-truth maps (``normal``, ``albedo``, ``roughness``, ``metallic``).
        pred: the model's maps, same keys.
        base: the photometric-stereo baseline's maps (``normal``, ``albedo``).
    """
    m = mask.astype(bool)
    nan = lambda a: np.where(m, a, np.nan)  # noqa: E731
    unpol, white_u = tone_map(maps[..., 0:3], m)
    lp, white_lp = tone_map(maps[..., 3:6], m)
    cp = nan(maps[..., 6:9].mean(-1))
    cp_lim = _signed_limit(cp[m])
    inputs = report.image_grid(
        fig_dir / f"{name}_inputs.png",
        [[unpol, lp, cp, m.astype(np.float32)]],
        [
            [
                f"unpol RGB (white {white_u:.3g})",
                f"LP RGB (white {white_lp:.3g})",
                "CP = s3/s0, mean of R, G, B",
                "mask (automatic)",
            ]
        ],  # fmt: skip
        [None, None, (-cp_lim, cp_lim), (0.0, 1.0)],
        [None, None, "RdBu_r", "gray"],
        nan_colour=NAN_COLOUR,
    )
    n_err, b_err = angle_map(pred["normal"], gt["normal"], m), angle_map(base["normal"], gt["normal"], m)
    a_err = nan(np.abs(pred["albedo"] - gt["albedo"]).mean(-1))
    ab_err = nan(np.abs(base["albedo"] - gt["albedo"]).mean(-1))
    nrm = lambda n: (n * 0.5 + 0.5) * m[..., None]  # noqa: E731
    r = lambda a: nan(a[..., 0] if a.ndim == 3 else a)  # noqa: E731
    results = report.image_grid(
        fig_dir / f"{name}_results.png",
        [
            [nrm(gt["normal"]), nrm(pred["normal"]), nrm(base["normal"]), n_err, b_err, normal_key()],
            [gt["albedo"] * m[..., None], pred["albedo"], base["albedo"], a_err, ab_err],
            [
                r(gt["roughness"]),
                r(pred["roughness"]),
                r(gt["metallic"]),
                r(pred["metallic"]),
                nan(np.abs(pred["roughness"][..., 0] - gt["roughness"].reshape(m.shape))),
            ],
        ],  # fmt: skip
        [
            [
                "normal: truth",
                "normal: ours",
                "normal: baseline (PS)",
                "ours: error (deg)",
                "baseline: error (deg)",
                NORMAL_KEY_TITLE,
            ],
            ["albedo: truth", "albedo: ours", "albedo: baseline (PS)", "ours: |error|", "baseline: |error|"],
            ["roughness: truth", "roughness: ours", "metallic: truth", "metallic: ours", "roughness |error|"],
        ],  # fmt: skip
        [
            [None, None, None, (0.0, 60.0), (0.0, 60.0), None],
            [None, None, None, (0.0, 0.5), (0.0, 0.5)],
            [(0.0, 1.0), (0.0, 1.0), (0.0, 1.0), (0.0, 1.0), (0.0, 0.5)],
        ],
        [
            [None, None, None, "magma", "magma", None],
            [None, None, None, "magma", "magma"],
            ["viridis", "viridis", "cividis", "cividis", "magma"],
        ],
        nan_colour=NAN_COLOUR,
    )
    inputs_caption = (
        f"{name}: the nine maps decoded from the raw capture, the model's input. Unpolarized (left) and linearly "
        "polarized (second) radiance, R, G, B as colour, each divided by its own 99.5th percentile of the object's "
        "pixels (the white point in its title) and shown with gamma 2.2, black off the object; comparing the white "
        "points tells how much of the light the object keeps polarized (a metal keeps most of it, so its "
        "unpolarized map is weak and noisy). Third: the circular part CP = s3/s0, averaged over R, G, B, red "
        "positive, blue negative, white 0, on a symmetric scale fitted to the object (colour bar; grey off the "
        "object). Right: the automatic foreground mask the model runs on."
    )
    results_caption = (
        f"{name}: rows normal, albedo, roughness/metallic; columns the ground truth, our prediction, the "
        "photometric-stereo baseline (PS) and the error maps. Normals are shown as (n + 1) / 2 in camera space: x "
        "(right) as red, y (up) as green, z (toward the camera) as blue; the key at the top right is a hemisphere "
        "facing the camera drawn the same way, so a pixel's colour there shows its normal direction. Normal errors "
        "are angles in degrees (0 to 60, brighter is worse), albedo errors the mean absolute difference over R, G, "
        "B (0 to 0.5). Roughness and metallic are on fixed 0-1 scales, so truth and prediction compare directly. "
        "Off the object: black in colour panels, grey in scalar ones."
    )
    root = fig_dir.parent
    return [
        (inputs.relative_to(root).as_posix(), inputs_caption),
        (results.relative_to(root).as_posix(), results_caption),
    ]


def relit_figure(
    path: Path, name: str, truth: Sequence[Path], frames: Sequence[Path], scores: Sequence[dict]
) -> tuple[Path, str]:
    """The relit truth (top) and prediction (bottom) frames of one scene; returns the PNG and its caption.

    Args:
        path: the PNG to write.
        name: scene name.
        truth: the truth's relit frames (``point_NNNN.png`` orbit frames, ``env_*.png`` the sky).
        frames: the prediction's relit frames, in the same order.
        scores: per prediction frame ``{"psnr": dB or None, ...}``.
    """
    titles = [("sky" if p.name.startswith("env") else f"point light {p.stem[-4:]}") for p in frames]
    fig = report.image_grid(
        path,
        [[_read_png(p) for p in truth], [_read_png(p) for p in frames]],
        [titles, [f"{t}: {_db(x['psnr'])}" for t, x in zip(titles, scores, strict=True)]],
        row_labels=["truth", "prediction"],
        cell=(2.2, 2.2),
    )
    caption = (
        f"{name}: the true maps (top) and the predicted maps (bottom) imported into Blender as Principled BSDF relief "
        f"assets ({name}.blend) and rendered alike with Cycles: point light N is frame N of a light orbiting the "
        f"object, sky a procedural sky. Frames are Blender's sRGB output, not rescaled. The number under each "
        f"prediction frame is its PSNR against the truth frame above it (higher is better)."
    )
    return fig, caption


def _db(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.1f} dB"


def _read_png(path: Path) -> np.ndarray:
    """An 8-bit PNG as ``(H, W, 3)`` float32 RGB in [0, 1]."""
    from PIL import Image  # noqa: PLC0415

    return np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255.0
