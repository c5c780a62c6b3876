"""The quantile Huber loss of IQN as a pure function (Dabney et al. 2018, Eq. 3-4)."""

from __future__ import annotations

import torch


def quantile_huber_loss(
    pred_XN: torch.Tensor,
    target_XM: torch.Tensor,
    taus_XN: torch.Tensor,
    kappa: float = 1.0,
) -> torch.Tensor:
    """Quantile Huber loss per leading index.

    Args:
        pred_XN: predicted quantiles Z_τi(s, a), shape ``[..., N]`` (any leading dims X).
        target_XM: target samples r + γ Z_τ'j(s', a*), shape ``[..., M]`` (no gradient taken).
        taus_XN: the fractions τ_i the predictions were made at, shape ``[..., N]``.
        kappa: Huber threshold κ > 0.

    Returns:
        ``[...]``: (1/M) Σ_j Σ_i |τ_i − 1{δ_ij < 0}| · L_κ(δ_ij) / κ with δ_ij = target_j −
        pred_i and L_κ the Huber loss; sum over the N predicted quantiles, mean over the
        M target samples, as in the IQN paper and Dopamine.
    """
    if kappa <= 0:
        raise ValueError(f"kappa must be > 0, got {kappa}")
    delta_XNM = target_XM.detach().unsqueeze(-2) - pred_XN.unsqueeze(-1)
    abs_delta = delta_XNM.abs()
    huber_XNM = torch.where(
        abs_delta <= kappa, 0.5 * delta_XNM.pow(2), kappa * (abs_delta - 0.5 * kappa)
    )
    weight_XNM = (taus_XN.unsqueeze(-1) - (delta_XNM.detach() < 0).to(pred_XN.dtype)).abs()
    return (weight_XNM * huber_XNM / kappa).sum(dim=-2).mean(dim=-1)
