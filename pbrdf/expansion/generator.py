"""Conditional VAE that maps Disney parameters to pBRDF PCA weights (the expansion's generator).

Condition ``c = (albedo R, G, B, roughness, metallic)`` in [0, 1]; data ``w`` = the PCA weights
of a table's wavelengths, flattened ``(W * (k_I + k_P),)`` and standardised with the training
set's mean and standard deviation. Encoder ``q(z | w, c)`` and decoder ``p(w | z, c)`` are small
MLPs; the loss is the reconstruction MSE plus ``beta`` times the KL divergence to N(0, I).
Sampling draws ``z ~ N(0, I)`` from a seeded generator, so the same seed and conditions give the
same weights. Checkpoints hold state dicts and a plain config dict, never pickled objects.
"""

from __future__ import annotations

import contextlib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

__all__ = ["GeneratorConfig", "WeightCVAE", "train_generator", "sample_weights", "save_generator", "load_generator"]


@dataclass(frozen=True)
class GeneratorConfig:
    """Sizes of the conditional VAE."""

    weight_dim: int
    cond_dim: int = 5
    latent_dim: int = 8
    hidden: int = 128
    beta: float = 1e-2


def _mlp(i: int, h: int, o: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(i, h), nn.SiLU(), nn.Linear(h, h), nn.SiLU(), nn.Linear(h, o))


class WeightCVAE(nn.Module):
    """``forward(w, c) -> (reconstruction, mu, logvar)``; ``decode(z, c) -> w`` (standardised)."""

    def __init__(self, cfg: GeneratorConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.encoder = _mlp(cfg.weight_dim + cfg.cond_dim, cfg.hidden, 2 * cfg.latent_dim)
        self.decoder = _mlp(cfg.latent_dim + cfg.cond_dim, cfg.hidden, cfg.weight_dim)
        self.register_buffer("w_mean", torch.zeros(cfg.weight_dim))
        self.register_buffer("w_std", torch.ones(cfg.weight_dim))

    def encode(self, w: torch.Tensor, c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(B, weight_dim)``, ``(B, cond_dim)`` -> mean and log-variance ``(B, latent_dim)``."""
        mu, logvar = self.encoder(torch.cat([w, c], dim=-1)).chunk(2, dim=-1)
        return mu, logvar.clamp(-10.0, 10.0)

    def decode(self, z: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
        """``(B, latent_dim)``, ``(B, cond_dim)`` -> standardised weights ``(B, weight_dim)``."""
        return self.decoder(torch.cat([z, c], dim=-1))

    def forward(self, w: torch.Tensor, c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Reparameterised pass: reconstruction, mu, logvar."""
        mu, logvar = self.encode(w, c)
        z = mu + torch.randn_like(mu) * torch.exp(0.5 * logvar)
        return self.decode(z, c), mu, logvar


@contextlib.contextmanager
def _one_thread():
    """Run tiny models on one thread: for MLPs this small, intra-op threading costs more than it gains."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


def train_generator(
    weights: NDArray,
    conditions: NDArray,
    *,
    steps: int = 2000,
    seed: int = 0,
    lr: float = 2e-3,
    latent_dim: int = 8,
    hidden: int = 128,
    beta: float = 1e-2,
) -> tuple[WeightCVAE, list[float]]:
    """Train the CVAE on ``weights (T, W, K)`` with ``conditions (T, 5)``; returns model and losses.

    Deterministic for a given seed on the CPU (full-batch AdamW; the seed sets initialisation and
    the reparameterisation noise).
    """
    w = np.asarray(weights, dtype=np.float64).reshape(len(weights), -1)
    c = np.asarray(conditions, dtype=np.float64)
    if c.ndim != 2 or c.shape[0] != w.shape[0]:
        raise ValueError(f"conditions must be (T, 5) matching weights (T, ...); got {c.shape} and {weights.shape}")
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(c))):
        raise ValueError("weights and conditions must be finite")
    with _one_thread():
        return _train(w, c, steps=steps, seed=seed, lr=lr, latent_dim=latent_dim, hidden=hidden, beta=beta)


def _train(w: NDArray, c: NDArray, *, steps: int, seed: int, lr: float, latent_dim: int, hidden: int, beta: float):
    gen = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    cfg = GeneratorConfig(weight_dim=w.shape[1], cond_dim=c.shape[1], latent_dim=latent_dim, hidden=hidden, beta=beta)
    model = WeightCVAE(cfg).double()
    mean, std = w.mean(axis=0), w.std(axis=0) + 1e-8
    model.w_mean.copy_(torch.from_numpy(mean))
    model.w_std.copy_(torch.from_numpy(std))
    wt = torch.from_numpy((w - mean) / std)
    ct = torch.from_numpy(c)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    losses = []
    for _ in range(steps):
        mu, logvar = model.encode(wt, ct)
        z = mu + torch.randn(mu.shape, generator=gen, dtype=mu.dtype) * torch.exp(0.5 * logvar)
        rec = model.decode(z, ct)
        kl = -0.5 * torch.mean(torch.sum(1 + logvar - mu**2 - logvar.exp(), dim=-1))
        loss = torch.mean((rec - wt) ** 2) + beta * kl
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        losses.append(float(loss.detach()))
    model.eval()
    return model, losses


@torch.no_grad()
def sample_weights(model: WeightCVAE, conditions: NDArray, *, seed: int = 0, temperature: float = 1.0) -> NDArray:
    """Weights for ``conditions (N, 5)``: ``(N, weight_dim)`` in the PCA's units (seeded)."""
    c = torch.as_tensor(np.asarray(conditions, dtype=np.float64)).to(model.w_mean.dtype)
    gen = torch.Generator().manual_seed(seed)
    with _one_thread():
        z = torch.randn((c.shape[0], model.cfg.latent_dim), generator=gen, dtype=c.dtype) * temperature
        w = model.decode(z, c) * model.w_std + model.w_mean
    return w.numpy()


def save_generator(path: str | Path, model: WeightCVAE) -> None:
    """Checkpoint: ``{"config": dict, "state_dict": tensors}`` (loadable with weights_only=True)."""
    from pbrdf.io.atomic import atomic_open  # noqa: PLC0415

    with atomic_open(path) as f:  # fsync, rename; the temporary file is removed on any error
        torch.save({"config": asdict(model.cfg), "state_dict": model.state_dict()}, f)


def load_generator(path: str | Path) -> WeightCVAE:
    """Inverse of :func:`save_generator`."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: generator checkpoint not found")
    try:
        ckpt = torch.load(path, weights_only=True)
        model = WeightCVAE(GeneratorConfig(**ckpt["config"])).double()
        model.load_state_dict(ckpt["state_dict"])
    except (KeyError, TypeError, RuntimeError) as exc:
        raise ValueError(f"{path}: not a generator checkpoint: {exc}") from None
    model.eval()
    return model
