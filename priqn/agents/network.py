"""The IQN network shared by every agent: fused encoder, cosine embedding, H heads.

Shapes (glossary used across ``priqn.agents``):

- ``B`` batch, ``T`` quantile fractions per state (N, N' or K), ``H`` heads,
  ``A`` actions, ``L`` latent width, ``C`` cosines.

``QuantileNetwork.forward(obs, taus_BT) -> quantiles_BHTA``. The encoder runs once per
state; only the cosine-embedding product and the two small head layers run per τ.
All H heads come out of one matmul (``hidden -> H*A``), so a 5-head agent costs the
same network time as a 1-head agent (measured in ``priqn bench train``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import torch
from torch import nn

from priqn.agents.comparators import quantile_grid
from priqn.agents.config import NetworkConfig

OBS_KEYS: tuple[str, ...] = ("bev", "lidar", "command", "kinematics")
"""Observation keys the encoder reads (the env's Dict space, ARCHITECTURE.md)."""


def to_tensors(obs: Mapping[str, Any], device: torch.device) -> dict[str, torch.Tensor]:
    """Numpy observation batch → the network's input tensors on ``device`` (uint8 grids stay
    uint8); what acting (:mod:`priqn.agents.policy`) and learning both feed the network.
    Tensors already on ``device`` (a replay batch with ``replay.storage`` device or pinned)
    pass as they are."""
    return {k: torch.as_tensor(v).to(device, non_blocking=True) for k, v in obs.items()}


def _grid_cnn(in_channels: int, channels: tuple[int, ...], size_px: int) -> tuple[nn.Module, int]:
    """Nature-DQN style CNN; strides adapt to the grid size. Returns (module, flat width)."""
    c1, c2, c3 = channels
    # 8x8/4, 4x4/2, 3x3/1 for >= 64 px grids (DQN); a gentler first stride for tiny grids.
    k1, s1 = (8, 4) if size_px >= 64 else (4, 2)
    net = nn.Sequential(
        nn.Conv2d(in_channels, c1, k1, s1),
        nn.ReLU(),
        nn.Conv2d(c1, c2, 4, 2),
        nn.ReLU(),
        nn.Conv2d(c2, c3, 3, 1),
        nn.ReLU(),
        nn.Flatten(),
    )
    with torch.no_grad():
        flat = net(torch.zeros(1, in_channels, size_px, size_px)).shape[1]
    return net, int(flat)


class QuantileNetwork(nn.Module):
    """Fused BEV + LiDAR + vector encoder → latent → IQN τ embedding → H×A quantiles.

    ``obs_shapes`` maps each key of :data:`OBS_KEYS` to its shape (read from the env's
    observation space); ``obs_scales`` maps the two uint8 grids to the factor that
    brings them to [0, 1] (1 / the space's ``high``; LiDAR counts are log-compressed:
    ``log1p(count) / log1p(high)``).
    """

    def __init__(
        self,
        obs_shapes: Mapping[str, tuple[int, ...]],
        obs_scales: Mapping[str, float],
        num_actions: int,
        num_heads: int,
        cfg: NetworkConfig | None = None,
    ) -> None:
        super().__init__()
        cfg = cfg or NetworkConfig()
        self.cfg = cfg
        self.num_actions = int(num_actions)
        self.num_heads = int(num_heads)
        bev_c, bev_h, bev_w = obs_shapes["bev"]
        lid_c, lid_h, lid_w = obs_shapes["lidar"]
        if bev_h != bev_w or lid_h != lid_w:
            raise ValueError(
                f"grids must be square, got bev {bev_h}x{bev_w}, lidar {lid_h}x{lid_w}"
            )
        self.bev_scale = float(obs_scales["bev"])
        self.lidar_scale = 1.0 / math.log1p(1.0 / float(obs_scales["lidar"]))
        self.bev_cnn, bev_flat = _grid_cnn(bev_c, cfg.conv_channels, bev_h)
        self.lidar_cnn, lid_flat = _grid_cnn(lid_c, cfg.conv_channels, lid_h)
        vec_in = int(obs_shapes["command"][0]) + int(obs_shapes["kinematics"][0])
        self.vector_mlp = nn.Sequential(nn.Linear(vec_in, cfg.vector_hidden), nn.ReLU())
        # Project the wide conv output to a small latent BEFORE the τ product (DESIGN §4).
        self.fuse = nn.Sequential(
            nn.Linear(bev_flat + lid_flat + cfg.vector_hidden, cfg.latent_dim), nn.ReLU()
        )
        self.tau_embed = nn.Sequential(nn.Linear(cfg.num_cosines, cfg.latent_dim), nn.ReLU())
        self.head_hidden = nn.Sequential(nn.Linear(cfg.latent_dim, cfg.hidden_dim), nn.ReLU())
        self.head_out = nn.Linear(cfg.hidden_dim, self.num_heads * self.num_actions)
        # i = 1..C (Dopamine); i = 0 would be a constant feature, redundant with the bias.
        self.register_buffer(
            "cosine_index_C",
            torch.arange(1, cfg.num_cosines + 1, dtype=torch.float32) * math.pi,
            persistent=False,
        )

    def encode(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """Observation batch (uint8 grids, float vectors) → latent ``[B, L]``."""
        bev = obs["bev"].float() * self.bev_scale
        # LiDAR point counts: log-compressed to [0, 1] (1 point ≈ 0.125 of 255 points).
        lidar = torch.log1p(obs["lidar"].float()) * self.lidar_scale
        kin = obs["kinematics"].float() * self.cfg.kinematics_scale
        vec = torch.cat([obs["command"].float(), kin], dim=1)
        feats = torch.cat([self.bev_cnn(bev), self.lidar_cnn(lidar), self.vector_mlp(vec)], dim=1)
        return self.fuse(feats)

    def quantiles(self, latent_BL: torch.Tensor, taus_BT: torch.Tensor) -> torch.Tensor:
        """Latent ``[B, L]`` and fractions ``[B, T]`` → quantiles ``[B, H, T, A]``."""
        B, T = taus_BT.shape
        cos_BTC = torch.cos(taus_BT.unsqueeze(-1) * self.cosine_index_C)
        phi_BTL = self.tau_embed(cos_BTC)
        x_BTL = latent_BL.unsqueeze(1) * phi_BTL
        out = self.head_out(self.head_hidden(x_BTL))  # [B, T, H*A]
        return out.view(B, T, self.num_heads, self.num_actions).permute(0, 2, 1, 3)

    def forward(self, obs: Mapping[str, torch.Tensor], taus_BT: torch.Tensor) -> torch.Tensor:
        """Observation batch and fractions ``[B, T]`` → quantiles ``[B, H, T, A]``."""
        return self.quantiles(self.encode(obs), taus_BT)


tau_grid = quantile_grid
"""The fixed acting/subset grid τ_k = (k + 0.5) / K (one grid: :func:`priqn.agents.comparators.quantile_grid`)."""
