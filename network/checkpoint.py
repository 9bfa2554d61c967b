"""Checkpoint files of :func:`network.train.train`: atomic writes, loading a model back, parameter hashes.

Two files per run, both ``torch.save`` dicts of plain values and tensors (read with ``weights_only=True``):

- ``model.pt``: ``format`` (:data:`CHECKPOINT_FORMAT`), ``config`` (:meth:`network.config.ModelConfig.to_dict`),
  ``inputs`` (the input variant, :mod:`network.inputs`) and ``model`` (the state dict);
- ``checkpoint.pt``: the same plus what resuming needs: ``optimizer``, ``step``, ``losses``, ``skipped``, ``rng``
  (every rank's RNG state), ``rank_params_sha256`` (:func:`params_sha256` per rank), ``world_size``, ``data``
  (dataset sizes) and ``train`` (the run's settings).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import torch

from pbrdf.io.atomic import temporary_path

from .config import ModelConfig
from .inputs import checkpoint_inputs
from .model.polar_model import PolarInverseModel

__all__ = ["CHECKPOINT_FORMAT", "load_checkpoint", "params_sha256", "save_checkpoint"]

#: Version of the checkpoint layout (files without ``format`` predate the current data order).
CHECKPOINT_FORMAT = 2


def save_checkpoint(path: Path, state: dict) -> None:
    """Write ``state`` with ``torch.save`` through a temporary file, so ``path`` is never half-written.

    Args:
        path: The destination file.
        state: The checkpoint dict.
    """
    tmp = temporary_path(path)
    torch.save(state, tmp)
    tmp.replace(path)


def load_checkpoint(path: str | Path) -> tuple[PolarInverseModel, dict]:
    """Model (eval mode) and the checkpoint dict from ``checkpoint.pt`` or ``model.pt`` written by training.

    The dict always has ``"inputs"`` (the input variant; ``"full"`` for files written before variants existed).

    Args:
        path: The checkpoint file.

    Returns:
        The model, with the stored weights loaded (strict), and the checkpoint dict.

    Raises:
        FileNotFoundError: If ``path`` is not a file.
        ValueError: If the file is not a model checkpoint (the message names the file).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    try:
        ckpt = torch.load(path, weights_only=True, map_location="cpu")
        model = PolarInverseModel(ModelConfig.from_dict(ckpt["config"]))
        model.load_state_dict(ckpt["model"])
        ckpt["inputs"] = checkpoint_inputs(ckpt)
    except (KeyError, RuntimeError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{path}: not a model checkpoint: {exc}") from None
    model.eval()
    return model, ckpt


def params_sha256(state: dict[str, torch.Tensor]) -> str:
    """SHA-256 over the bytes of every tensor of a state dict, in its order (bitwise identity check).

    Args:
        state: A state dict.

    Returns:
        The hex digest.
    """
    h = hashlib.sha256()
    for key, value in state.items():
        h.update(key.encode())
        h.update(value.detach().cpu().contiguous().view(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()
