"""The learner's two network passes replayed from CUDA graphs (``learner.compile = "graphs"``).

At batch 32 an update is launch-bound on a GPU: a few hundred small kernels, each costing
more to launch than to run. A CUDA graph records those launches once and replays them
with one call. What is recorded here is exactly the eager update's work, with the same
kernels on the same inputs:

- the target network's forward pass (no gradients), and
- the online forward pass, the quantile Huber loss and its backward pass, which leaves
  the gradients in the parameters' ``.grad``.

τ sampling, Algorithm 1's target rules (data-dependent subsets), gradient clipping and
Adam stay eager, so every random stream is consumed as in the eager update.

Each :class:`GraphedPasses` belongs to one learner and holds its own graphs and memory
pool, one pair per batch shape it has seen: several learners in one process, a learner
resumed in place (``load_state_dict`` copies into the same parameter tensors) and a
target sync (likewise a copy) all replay correctly, which torch.compile's shared CUDA-graph
trees did not (docs/implementation-details.md §12). A graph reads its inputs from, and
writes its outputs to, fixed tensors: an output is valid until the next replay of the
same graph, which :class:`priqn.agents.learner.Learner` respects by using each one before
the next update.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import torch
from torch import nn

WARMUP_PASSES = 3
"""Eager passes on a side stream before a capture (cuBLAS/cuDNN workspaces and autograd's
lazy state are created outside the graph, as the CUDA-graph documentation asks)."""

LossFn = Callable[..., tuple[torch.Tensor, torch.Tensor]]


def _signature(tensors: Mapping[str, torch.Tensor]) -> tuple[tuple[str, tuple[int, ...], Any], ...]:
    """What a graph was recorded for: every input's name, shape and dtype."""
    return tuple((k, tuple(t.shape), t.dtype) for k, t in tensors.items())


class _Recorded:
    """One graph with its fixed inputs (by name), outputs and the gradients it writes."""

    def __init__(self, graph: torch.cuda.CUDAGraph, inputs: dict[str, torch.Tensor],
                 outputs: tuple[torch.Tensor, ...], grads: list[torch.Tensor | None]) -> None:  # fmt: skip
        self.graph = graph
        self.inputs = inputs
        self.outputs = outputs
        self.grads = grads

    def replay(self, inputs: Mapping[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
        for name, value in inputs.items():
            self.inputs[name].copy_(value, non_blocking=True)
        self.graph.replay()
        return self.outputs


class GraphedPasses:
    """One learner's target forward and online forward + loss + backward, as CUDA graphs."""

    def __init__(self, online: nn.Module, target: nn.Module, loss_fn: LossFn) -> None:
        self.online = online
        self.target = target
        self.loss_fn = loss_fn
        self.params = [p for p in online.parameters() if p.requires_grad]
        self.pool = torch.cuda.graph_pool_handle()
        self._target_graphs: dict[Any, _Recorded] = {}
        self._loss_graphs: dict[Any, _Recorded] = {}

    def target_forward(
        self, obs: Mapping[str, torch.Tensor], taus_BT: torch.Tensor
    ) -> torch.Tensor:
        """``target(obs, taus_BT)``; valid until this learner's next target pass."""
        inputs = {**{f"obs.{k}": v for k, v in obs.items()}, "taus": taus_BT}
        key = _signature(inputs)
        rec = self._target_graphs.get(key)
        if rec is None:
            rec = self._target_graphs[key] = self._record(inputs, self._target_pass, grads=False)
        return rec.replay(inputs)[0]

    def loss_and_backward(self, obs: Mapping[str, torch.Tensor], taus_BGN: torch.Tensor,
                          action_B: torch.Tensor, target_BHNp: torch.Tensor, kappa: float,
                          ) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
        """(loss, predicted quantiles ``[B, H, N]``), with the loss's gradients left in the
        online parameters' ``.grad`` (replacing, not adding to, what was there)."""
        inputs = {
            **{f"obs.{k}": v for k, v in obs.items()},
            "taus": taus_BGN,
            "action": action_B,
            "target": target_BHNp,
        }
        key = (_signature(inputs), float(kappa))
        rec = self._loss_graphs.get(key)
        if rec is None:
            rec = self._loss_graphs[key] = self._record(
                inputs, lambda x: self._loss_pass(x, kappa), grads=True
            )
        loss, pred_BHN = rec.replay(inputs)
        for p, grad in zip(self.params, rec.grads, strict=True):
            p.grad = grad  # this graph's gradient buffers (another shape has its own)
        return loss, pred_BHN

    def _target_pass(self, x: Mapping[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
        with torch.no_grad():
            return (self.target(_obs_of(x), x["taus"]),)

    def _loss_pass(self, x: Mapping[str, torch.Tensor], kappa: float) -> tuple[torch.Tensor, ...]:
        loss, pred_BHN = self.loss_fn(
            self.online, _obs_of(x), x["taus"], x["action"], x["target"], kappa, False
        )
        return loss, pred_BHN.detach()

    def _record(self, inputs: Mapping[str, torch.Tensor],
                pass_fn: Callable[[Mapping[str, torch.Tensor]], tuple[torch.Tensor, ...]],
                grads: bool) -> _Recorded:  # fmt: skip
        """Warm up ``pass_fn`` on a side stream, then record it into a graph of this pool.
        With ``grads`` the pass's loss (first output) is back-propagated inside the graph.
        Neither the warm-up nor the recording changes a weight or an existing ``.grad``."""
        static = {k: v.detach().clone() for k, v in inputs.items()}
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            for _ in range(WARMUP_PASSES):
                out = pass_fn(static)
                if grads:
                    torch.autograd.grad(out[0], self.params, allow_unused=True)  # .grad untouched
        torch.cuda.current_stream().wait_stream(side)
        kept = [p.grad for p in self.params]
        for p in self.params:
            p.grad = None  # the recorded backward allocates its own buffers in the pool
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph, pool=self.pool, capture_error_mode="thread_local"):
            outputs = pass_fn(static)
            if grads:
                outputs[0].backward()
        recorded_grads = [p.grad for p in self.params]
        for p, grad in zip(self.params, kept, strict=True):
            p.grad = grad
        return _Recorded(graph, static, tuple(o.detach() for o in outputs), recorded_grads)


def _obs_of(x: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    return {k[4:]: v for k, v in x.items() if k.startswith("obs.")}
