"""Decode a raw HDR capture folder (IMX250MYR polarization mosaics) into the nine network input maps.

    python headless/decode.py --input CAPTURE_DIR --out OUT_DIR [--grid half|full] [--preview] [--quiet]
    python -m headless.decode --input CAPTURE_DIR --out OUT_DIR

Writes OUT_DIR/maps.npy ((H', W', 9) float32), OUT_DIR/mask.npy ((H', W') bool) and, with
--preview, OUT_DIR/preview.png, then prints the written paths. The files are written together
into a temporary folder and renamed into place; nothing is written unless loading and decoding
succeed. Bad input prints one line "error: <message>" on stderr and exits with status 2
(nothing else: warnings raised on the way are dropped); so does a capture that decodes to no
usable pixel (all dark, all saturated, dark then saturated, black level at or above the data).
A capture whose maps hold no object above the noise floor, or whose automatic object mask covers
nearly the whole frame without dark frames (room light on the background), is decoded but prints
one line "warning: <message>" on stderr.
"""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

if not __package__:  # run as a file (python headless/x.py, blender -b -P): the repository root first
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from headless._cli import held_warnings  # noqa: E402
from pbrdf.data.capture import CAPTURE_FORMAT, CAPTURE_JSON, load_capture  # noqa: E402
from pbrdf.data.capture_decode import check_usable, decode_capture  # noqa: E402
from pbrdf.data.capture_rig import read_rig, with_rig  # noqa: E402
from pbrdf.io.atomic import atomic_folder  # noqa: E402
from pbrdf.sensor.decode import NINE_MAP_NAMES  # noqa: E402

EXIT_BAD_INPUT = 2

_EPILOG = f"""\
capture folder format ({CAPTURE_FORMAT}):
  CAPTURE_DIR/{CAPTURE_JSON}   JSON object with
      "format": "{CAPTURE_FORMAT}"
      "exposures_s": [0.01, 0.02, 0.1, 0.2]      exposure times in seconds
      "raw_files": ["raw_0010.0ms.png", ...]     one raw per exposure, same order
      "black_level": 16.0, "white_level": 4095   optional, in DN (white = 2**bits - 1)
      "bits": 12, "pattern_offset": [0, 0]       optional
      "camera_model": {{...}}                      optional calibration (CameraModel.to_dict())
  CAPTURE_DIR/raw_*.png|.tif|.tiff|.npy
      single-channel IMX250MYR raw mosaics (H, W), H and W multiples of 4, black level
      included, 16-bit grayscale PNG/TIFF or integer .npy
  See pbrdf/data/capture.py (save_capture writes this layout).

outputs:
  OUT_DIR/maps.npy     (H', W', 9) float32, order {", ".join(NINE_MAP_NAMES)}
  OUT_DIR/mask.npy     (H', W') bool, True where the maps are valid
  OUT_DIR/preview.png  with --preview: the nine maps as a 3x3 grid
  H', W' = H/2, W/2 for --grid half (default), H, W for --grid full.
"""


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (see the module docstring)."""
    parser = argparse.ArgumentParser(
        prog="decode.py", description=__doc__, epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--input", type=Path, metavar="CAPTURE_DIR", required=True,
                        help="capture folder holding capture.json and the raws")  # fmt: skip
    parser.add_argument("--out", type=Path, required=True, help="output folder (created if missing)")
    parser.add_argument(
        "--grid", choices=("half", "full"), default="half", help="output grid (default: half resolution)"
    )
    parser.add_argument("--preview", action="store_true", help="also write preview.png of the nine maps")
    parser.add_argument("--rig", type=Path, metavar="RIG_JSON",
                        help="decode with a calibrated rig (headless/calibrate.py's rig.json; bracket and sensor stay "
                        "capture.json's)")  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="no progress output (decode shows none)")
    return parser


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)
    return buf.getvalue()


def _preview_png(maps: np.ndarray, mask: np.ndarray) -> bytes:
    """3x3 grid (rows unpol, LP, CP; columns R, G, B) as PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    h, w = mask.shape
    fig = Figure(figsize=(9.0, 9.0 * h / w + 0.6), layout="constrained")
    axes = fig.subplots(3, 3, squeeze=False)
    for row in range(3):
        block = maps[..., 3 * row : 3 * row + 3]
        if row == 2:  # CP in [-1, 1]
            vmin, vmax, cmap = -1.0, 1.0, "coolwarm"
        else:  # one scale per row so colours compare
            vals = block[mask] if mask.any() else block.reshape(-1)
            vmin, vmax, cmap = 0.0, float(np.percentile(vals, 99.5)) if vals.size else 1.0, "gray"
            vmax = vmax if vmax > 0 else 1.0
        for col in range(3):
            k = 3 * row + col
            ax = axes[row][col]
            im = ax.imshow(np.where(mask, maps[..., k], np.nan), vmin=vmin, vmax=vmax, cmap=cmap)
            ax.set_title(NINE_MAP_NAMES[k], fontsize=9)
            ax.set_axis_off()
        fig.colorbar(im, ax=list(axes[row]), shrink=0.8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    return buf.getvalue()


def run(
    capture_dir: Path, out: Path, *, grid: str = "half", preview: bool = False, rig: Path | None = None
) -> list[Path]:
    """Load, decode and write the outputs.

    Args:
        capture_dir: capture folder (``capture.json`` and the raws).
        out: output folder, created if missing.
        grid: ``"half"`` or ``"full"`` output grid.
        preview: also write ``preview.png``.
        rig: a calibrated rig file to decode with (:func:`pbrdf.data.capture_rig.with_rig`), or None.

    Returns:
        The written paths.

    Raises:
        ValueError: bad capture content, or nothing usable decoded (:func:`check_usable`).
        OSError: unreadable capture or unwritable output folder.

    Warns:
        CaptureWarning: no object stands out from the background, or the automatic mask covers
            nearly the whole frame of a capture without dark frames.
    """
    capture = load_capture(capture_dir)
    capture = capture if rig is None else with_rig(capture, read_rig(rig))
    decoded = decode_capture(capture, grid=grid)
    check_usable(decoded, capture)
    # Render everything before writing anything.
    outputs = {
        "maps.npy": _npy_bytes(decoded.maps.astype(np.float32, copy=False)),
        "mask.npy": _npy_bytes(decoded.mask.astype(bool, copy=False)),
    }
    if preview:
        outputs["preview.png"] = _preview_png(decoded.maps, decoded.mask)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out}: output path exists and is not a folder")
    with atomic_folder(out, merge=True) as staging:
        for name, data in outputs.items():
            (staging / name).write_bytes(data)
    return [out / name for name in outputs]


def main(argv: list[str] | None = None) -> int:
    """Run the script; returns the exit status (0, or 2 for bad input)."""
    args = build_parser().parse_args(argv)

    def work() -> int:
        for path in run(args.input, args.out, grid=args.grid, preview=args.preview, rig=args.rig):
            print(path)
        return 0

    return held_warnings(work, status=EXIT_BAD_INPUT)


if __name__ == "__main__":
    raise SystemExit(main())
