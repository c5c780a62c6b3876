"""Quantile Huber loss against hand-computed values."""

from __future__ import annotations

import pytest
import torch

from priqn.agents.loss import quantile_huber_loss


def test_hand_computed_kappa_1():
    # pred (0, 1) at tau (0.25, 0.75); targets (0.5, 2).
    # i=0: d=0.5 -> 0.125*0.25 ; d=2 -> 1.5*0.25      (tau - 0 = 0.25)
    # i=1: d=-0.5 -> 0.125*|0.75-1| ; d=1 -> 0.5*0.75
    # sum over i: j=0: 0.0625, j=1: 0.75 ; mean over j: 0.40625
    pred = torch.tensor([0.0, 1.0])
    target = torch.tensor([0.5, 2.0])
    taus = torch.tensor([0.25, 0.75])
    assert quantile_huber_loss(pred, target, taus, 1.0).item() == pytest.approx(0.40625)


def test_hand_computed_kappa_2_is_divided_by_kappa():
    # kappa=2: every |d| <= 2 is quadratic, then / kappa.
    # i=0: 0.5*0.25^2... d=0.5 -> 0.125/2*0.25=0.015625 ; d=2 -> 2/2*0.25=0.25
    # i=1: d=-0.5 -> 0.0625*0.25=0.015625 ; d=1 -> 0.25*0.75=0.1875
    # j=0: 0.03125, j=1: 0.4375 -> mean 0.234375
    pred = torch.tensor([0.0, 1.0])
    target = torch.tensor([0.5, 2.0])
    taus = torch.tensor([0.25, 0.75])
    assert quantile_huber_loss(pred, target, taus, 2.0).item() == pytest.approx(0.234375)


def test_batched_leading_dims_and_no_target_gradient():
    pred = torch.tensor([[[0.0, 1.0]], [[0.0, 1.0]]], requires_grad=True)  # [2, 1, 2]
    target = torch.tensor([[[0.5, 2.0]], [[0.0, 1.0]]], requires_grad=True)
    taus = torch.tensor([0.25, 0.75]).expand(2, 1, 2)
    loss = quantile_huber_loss(pred, target, taus)
    assert loss.shape == (2, 1)
    assert loss[0, 0].item() == pytest.approx(0.40625)
    loss.sum().backward()
    assert target.grad is None
    # d/dpred_0 of row 0: -(0.25*0.5 + 0.25*1)/2 (linear part clipped at kappa) = -0.1875
    assert pred.grad[0, 0, 0].item() == pytest.approx(-0.1875)


def test_minimiser_is_the_quantile():
    # For many targets, the loss-minimising prediction at tau is the tau-quantile.
    target = torch.arange(101, dtype=torch.float32) / 10.0  # 0..10
    grid = torch.linspace(0, 10, 1001)
    losses = torch.stack(
        [quantile_huber_loss(g.view(1), target, torch.tensor([0.9]), 1.0) for g in grid]
    )
    best = grid[losses.argmin()].item()
    assert best == pytest.approx(9.0, abs=0.6)


def test_kappa_must_be_positive():
    with pytest.raises(ValueError):
        quantile_huber_loss(torch.zeros(1), torch.zeros(1), torch.zeros(1), 0.0)
