"""Checkpoint files of :func:`network.train.train`: atomic writes, loading a model back, parameter hashes.

Two files per run, both ``torch.save`` dicts of plain values and tensors (read with ``weights_only=True``):

- ``model.pt``: ``format`` (:data:`CHECKPOINT_FORMAT`), ``config`` (:meth:`network.config.ModelConfig.to_dict`),
  ``inputs`` (the input variant, :mod:`network.inputs`), ``input_scale`` (``"calibrated"`` or
  ``"exposure-invariant"``, :mod:`network.data`), ``model`` (the state dict), ``step`` and
  ``params_sha256`` (:func:`params_sha256` of ``model``: which checkpoint it was cut from, see
  :func:`model_file_is_current`);
- ``checkpoint.pt``: the same plus what resuming needs: ``optimizer``, ``step``, ``losses``, ``skipped``, ``rng``
  (every rank's RNG state), ``rank_params_sha256`` (:func:`params_sha256` per rank), ``world_size``, ``data``
  (dataset sizes) and ``train`` (the run's settings).
"""

from __future__ import annotations

import dataclasses
import hashlib
import pickle
from pathlib import Path

import torch

from pbrdf.io.atomic import atomic_open

from .config import ModelConfig
from .data import checkpoint_input_scale
from .inputs import checkpoint_inputs
from .model.layers import skip_init
from .model.polar_model import PolarInverseModel

__all__ = [
    "CHECKPOINT_FORMAT",
    "MODEL_KEYS",
    "init_from_checkpoint",
    "load_checkpoint",
    "require_trained_with",
    "model_file_is_current",
    "model_file_state",
    "params_sha256",
    "save_checkpoint",
]

#: Version of the checkpoint layout (files without ``format`` predate the current data order).
CHECKPOINT_FORMAT = 2

#: Keys of a checkpoint that ``model.pt`` copies (besides ``step`` and ``params_sha256``).
MODEL_KEYS = ("format", "config", "inputs", "input_scale", "model")


def save_checkpoint(path: Path, state: dict) -> None:
    """Write ``state`` with ``torch.save`` atomically (:func:`pbrdf.io.atomic.atomic_open`).

    ``path`` is never half-written; on an error the temporary file is removed (a killed process leaves
    it: :func:`pbrdf.io.atomic.remove_leftovers` takes it on the next run).

    Args:
        path: The destination file.
        state: The checkpoint dict.
    """
    with atomic_open(path) as f:
        torch.save(state, f)


def model_file_state(ckpt: dict, sha256: str | None = None) -> dict:
    """What ``model.pt`` holds for a training checkpoint: its :data:`MODEL_KEYS`, ``step``, ``params_sha256``.

    Args:
        ckpt: A ``checkpoint.pt`` dict (``step`` and ``model`` required).
        sha256: :func:`params_sha256` of ``ckpt["model"]`` if known (computed otherwise).

    Returns:
        The ``model.pt`` dict (tensors shared with ``ckpt``).
    """
    state = {k: ckpt[k] for k in MODEL_KEYS if k in ckpt}
    state["step"] = int(ckpt["step"])
    state["params_sha256"] = sha256 if sha256 is not None else params_sha256(ckpt["model"])
    return state


def model_file_is_current(path: Path, step: int, sha256: str) -> bool:
    """Whether ``path`` (a ``model.pt``) was written from the checkpoint of ``step`` with parameters ``sha256``.

    A missing or unreadable file, or one without ``step``/``params_sha256`` (written before they
    existed, or by a run killed between its checkpoint and its model file), is not current.
    """
    if not Path(path).is_file():
        return False
    try:
        stored = torch.load(path, weights_only=True, map_location="cpu", mmap=True)  # tensors stay on disk
    except Exception:  # noqa: BLE001 - any unreadable file is simply stale
        return False
    return isinstance(stored, dict) and stored.get("step") == step and stored.get("params_sha256") == sha256


def load_checkpoint(path: str | Path) -> tuple[PolarInverseModel, dict]:
    """Model (eval mode) and the checkpoint dict from ``checkpoint.pt`` or ``model.pt`` written by training.

    The dict always has ``"inputs"`` (the input variant; ``"full"`` for files written before variants existed)
    and ``"input_scale"`` (``"exposure-invariant"`` for files written before calibrated input existed).

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
    except (pickle.UnpicklingError, EOFError, KeyError, RuntimeError, ValueError, OSError, UnicodeDecodeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ValueError(f"{path}: not a readable torch checkpoint ({type(exc).__name__}: {first[:200]})") from None
    if not isinstance(ckpt, dict):
        raise ValueError(f"{path}: not a model checkpoint (holds a {type(ckpt).__name__}, not a dict)")
    try:
        with skip_init():  # the random init would be overwritten at once
            model = PolarInverseModel(ModelConfig.from_dict(ckpt["config"]))
        model.load_state_dict(ckpt["model"])
        ckpt["inputs"] = checkpoint_inputs(ckpt)
        ckpt["input_scale"] = checkpoint_input_scale(ckpt)
    except (KeyError, RuntimeError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{path}: not a model checkpoint: {exc}") from None
    model.eval()
    return model, ckpt


def init_from_checkpoint(model: PolarInverseModel, path: str | Path) -> dict:
    """Start ``model`` from a trained checkpoint's weights (fine-tuning a light-input model from a light-blind one).

    The checkpoint's configuration must equal ``model.config`` except ``light_input``; weights the
    checkpoint lacks (the light input's ``light_embed`` and ``decoder.chi``) keep ``model``'s own
    zero initialisation, so the model starts out as exactly the checkpoint's function.

    Args:
        model: the freshly built model.
        path: a ``model.pt`` or ``checkpoint.pt``.

    Returns:
        The checkpoint dict (:func:`load_checkpoint`'s, with ``inputs`` and ``input_scale``).

    Raises:
        ValueError: a different configuration, or weights other than the light input's missing or extra.
    """
    _, ckpt = load_checkpoint(path)
    theirs = ModelConfig.from_dict(ckpt["config"])
    if dataclasses.replace(theirs, light_input=model.config.light_input) != model.config:
        raise ValueError(f"{path}: init_from checkpoint's model config differs from the run's (other than light_input)")
    result = model.load_state_dict(ckpt["model"], strict=False)
    allowed = {"light_embed.weight", "decoder.chi.weight"}
    if result.unexpected_keys or set(result.missing_keys) - allowed:
        raise ValueError(f"{path}: init_from weights do not fit the model (missing {result.missing_keys}, "
                         f"unexpected {result.unexpected_keys})")  # fmt: skip
    return ckpt


def require_trained_with(ckpt: dict, path: str | Path, role: str, inputs: str, input_scale: str) -> None:
    """ValueError unless a loaded checkpoint (``role``: its use in the run) has this input variant and scale."""
    for name, want in (("inputs", inputs), ("input_scale", input_scale)):
        if ckpt[name] != want:
            raise ValueError(f"{path}: {role} checkpoint was trained with {name}={ckpt[name]!r}, not {want!r}")


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
