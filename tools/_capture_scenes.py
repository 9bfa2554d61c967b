"""Shared by the diagnostic tools: a checkpoint's predictions on rendered splits, through the capture path.

Each scene goes through :func:`network.evaluation.predict_scene`, the evaluation's own path (raw
brackets, decode, automatic mask), without the photometric-stereo baseline.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any


def add_arguments(parser: argparse.ArgumentParser, inputs: list[Path], limit: int) -> None:
    """``--input`` (split folders), ``--limit`` (scenes per split) and ``--checkpoint``."""
    parser.add_argument("--input", type=Path, nargs="+", default=inputs,
                        help="rendered split folders (default: " + " ".join(str(p) for p in inputs) + ")")  # fmt: skip
    parser.add_argument("--limit", type=int, default=limit, help=f"scenes per split (default {limit})")
    parser.add_argument("--checkpoint", type=Path, help="default: the shipped model")


def load(checkpoint: Path | None) -> tuple[Any, dict, dict]:
    """The model, its checkpoint dict and the training statistics beside it (2 torch threads)."""
    import torch

    from network.checkpoint import load_checkpoint
    from network.constant import STATS_FILE, load_statistics
    from network.infer import DEFAULT_CHECKPOINT

    torch.set_num_threads(2)
    path = Path(checkpoint or DEFAULT_CHECKPOINT)
    model, ckpt = load_checkpoint(path)
    return model, ckpt, load_statistics(path.parent / STATS_FILE)


def capture_scenes(model: Any, ckpt: Mapping, stats: Mapping, root: Path, limit: int) -> Iterator[Any]:
    """:class:`network.evaluation.ScenePredictions` of the first ``limit`` completed scenes of ``root``."""
    from network.data import checkpoint_input_scale
    from network.evaluation import predict_scene
    from network.inputs import checkpoint_inputs
    from pbrdf.data import dataset as pdataset

    variant, scale = checkpoint_inputs(ckpt), checkpoint_input_scale(ckpt)
    for i in sorted(pdataset.completed_indices(root, verify_hash=False))[:limit]:
        yield predict_scene(model, variant, root, i, stats, input_scale=scale, baseline=False)
