"""IQN learning step shared by every agent: sampled τ, target network, quantile Huber loss.

The agent decides only two things here (``priqn.agents.registry.Agent``): what reward
each head learns and which next action each head bootstraps from. Everything else —
τ sampling, the target network, the loss, Adam — is the same for all four agents.
"""

from __future__ import annotations

import copy
import hashlib
from collections.abc import Callable, Mapping
from typing import Any

import torch

from priqn.agents.config import COMPILE_MODES, LearnerConfig
from priqn.agents.graphs import GraphedPasses
from priqn.agents.loss import quantile_huber_loss
from priqn.agents.network import QuantileNetwork, tau_grid, to_tensors
from priqn.agents.registry import Agent
from priqn.errors import PriqnError


class UpdateStats(Mapping[str, float]):
    """One update's statistics (loss, mean prediction, mean target |S_r|): kept as 0-d
    tensors on the learner's device and turned into floats only when first read, so an
    update costs no host sync; the loop reads the latest update's when it logs. The
    floats are the ones an eager ``float(tensor)`` would give."""

    def __init__(self, tensors: Mapping[str, torch.Tensor]) -> None:
        self._tensors = dict(tensors)
        self._floats: dict[str, float] | None = None

    def _read(self) -> dict[str, float]:
        if self._floats is None:  # one host sync, for all of them
            values = torch.stack([t.double() for t in self._tensors.values()]).tolist()
            self._floats = dict(zip(self._tensors, values, strict=True))
        return self._floats

    @property
    def pending(self) -> bool:
        """True until the statistics are first read (no host sync has happened)."""
        return self._floats is None

    def __getitem__(self, key: str) -> float:
        return self._read()[key]

    def __iter__(self) -> Any:
        return iter(self._tensors)

    def __len__(self) -> int:
        return len(self._tensors)


def make_adam(params: Any, lr: float, eps: float, device: torch.device) -> torch.optim.Adam:
    """Adam, fused where this torch build supports it on ``device`` (faster on CPU too)."""
    params = list(params)
    try:
        return torch.optim.Adam(params, lr=lr, eps=eps, fused=True)
    except (RuntimeError, TypeError, ValueError):
        return torch.optim.Adam(params, lr=lr, eps=eps)


def _own_group(quantiles_BHTA: torch.Tensor, groups: int) -> torch.Tensor:
    """Head h's quantiles at its own τ group: ``[B, H, G·T, A]`` → ``[B, H, T, A]``.

    With one group every head already sees the same τ; with G = H the network was
    evaluated at every head's τ and head h keeps block h (the diagonal).
    """
    if groups == 1:
        return quantiles_BHTA
    B, H, GT, A = quantiles_BHTA.shape
    blocks = quantiles_BHTA.view(B, H, groups, GT // groups, A)
    return torch.diagonal(blocks, dim1=1, dim2=2).permute(0, 3, 1, 2)


AUTO_UPDATE: dict[str, str] = {"cuda": "graphs"}
"""What ``learner.compile = "auto"`` runs, by device type (any other device: ``eager``).

- ``cuda``: ``graphs`` (:mod:`priqn.agents.graphs`). At batch 32 the update is
  launch-bound there; recording its passes as CUDA graphs removes the launches without
  changing a kernel: 3.39x (IQN) and 2.91x (Pr-IQN) eager updates/s at the paper preset
  on an H200 (2026-11-28), against torch.compile's (``on``) 2.36x and 2.29x in the same
  rounds. torch.compile's shared CUDA-graph trees also failed ``tests/test_cuda.py``'s
  resume and device-move cases and aborted the process at exit (an H100, 2026-11-26;
  docs/implementation-details.md §12).
- ``cpu``: eager. On this project's 2-core CPU the compiled update was no faster, and the
  eager update keeps seeded runs bit for bit.
"""

UPDATE_KINDS: tuple[str, ...] = ("eager", "graphs", "inductor")
"""How an update runs (:func:`resolve_compile`): the eager kernels; the same kernels
replayed from CUDA graphs; or torch.compile's inductor kernels (CUDA graphs on CUDA)."""


def has_compiler(device: torch.device) -> bool:
    """Whether torch.compile's default back-end can build kernels for ``device`` here
    (Triton for CUDA; the CPU back-end needs a C++ compiler, which is not checked)."""
    if device.type == "cuda":
        try:
            from torch.utils._triton import has_triton
        except ImportError:
            return False
        return bool(has_triton())
    return device.type == "cpu"


def resolve_compile(setting: str, device: torch.device, bf16: bool = False) -> str:
    """``learner.compile`` on ``device`` → the update's kind (:data:`UPDATE_KINDS`).

    ``"auto"`` runs :data:`AUTO_UPDATE` for the device type (eager where bf16 autocast is
    on, which the graphs do not record); ``"graphs"`` the CUDA graphs (a CPU device or
    bf16 is a one-line error); ``"on"`` torch.compile (a missing compiler is a one-line
    error); ``"off"`` the eager update, bit for bit.
    """
    if setting not in COMPILE_MODES:
        raise PriqnError(
            f"learner.compile: unknown {setting!r} (valid: {', '.join(COMPILE_MODES)})"
        )
    if setting == "off":
        return "eager"
    if setting == "auto":
        kind = AUTO_UPDATE.get(device.type, "eager")
        return "eager" if kind == "graphs" and bf16 else kind
    if setting == "graphs":
        if device.type != "cuda" or bf16:
            why = "bf16 autocast" if device.type == "cuda" else f"a {device.type} device"
            raise PriqnError(
                f"learner.compile = 'graphs' records CUDA graphs, not possible with {why}; "
                "set learner.compile = 'auto' or 'off'"
            )
        return "graphs"
    if not has_compiler(device):
        raise PriqnError(
            f"learner.compile = 'on': torch.compile has no back-end for {device.type} here "
            "(CUDA needs the triton package); set learner.compile = 'auto' or 'off'"
        )
    return "inductor"


def _online_loss(
    online: torch.nn.Module,
    obs: Mapping[str, torch.Tensor],
    taus_BGN: torch.Tensor,
    action_B: torch.Tensor,
    target_BHNp: torch.Tensor,
    kappa: float,
    bf16: bool,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Online quantiles at the sampled τ → (loss, predicted quantiles ``[B, H, N]``).

    The part of an update that needs gradients; :class:`Learner` runs it as it is (eager)
    or compiled (``learner.compile``), with the same operations in the same order.
    """
    B, G, N = taus_BGN.shape
    H = target_BHNp.shape[1]
    with torch.autocast(taus_BGN.device.type, torch.bfloat16, enabled=bf16):
        quantiles_BHNA = _own_group(online(obs, taus_BGN.reshape(B, G * N)).float(), G)
    pred_BHN = quantiles_BHNA.gather(3, action_B[:, None, None, None].expand(B, H, N, 1))
    pred_BHN = pred_BHN.squeeze(3)
    taus_BHN = taus_BGN.expand(B, H, N)
    loss_BH = quantile_huber_loss(pred_BHN, target_BHNp, taus_BHN, kappa)
    # Heads are independent learners on one encoder: sum over heads, mean over batch.
    return loss_BH.mean(dim=0).sum(), pred_BHN


class Learner:
    """Online + target network, Adam, and one IQN update per :meth:`update` call.

    How the update runs is ``cfg.compile`` resolved on the device (:func:`resolve_compile`):
    eager; ``graphs`` (CUDA, the default there), where the target network's forward pass
    and the online forward + loss + backward are replayed from this learner's own CUDA
    graphs (:mod:`priqn.agents.graphs`); or ``inductor`` (``on``), where they run through
    ``torch.compile`` (mode ``"reduce-overhead"`` on CUDA). τ are drawn eagerly from the
    same generator in every kind, and the target rules (Algorithm 1 for Pr-IQN), Adam and
    gradient clipping stay eager.
    """

    def __init__(
        self,
        network: QuantileNetwork,
        agent: Agent,
        cfg: LearnerConfig,
        device: torch.device,
        tau_seed: int,
    ) -> None:
        self.cfg = cfg
        self.agent = agent
        self.device = device
        self.online = network.to(device)
        self.target = copy.deepcopy(self.online).requires_grad_(False)
        self.optimizer = make_adam(self.online.parameters(), cfg.lr, cfg.adam_eps, device)
        self.tau_generator = torch.Generator(device=device)
        self.tau_generator.manual_seed(int(tau_seed))
        self.grid_K = tau_grid(cfg.num_quantiles, device)
        self.updates = 0
        self.update_kind = resolve_compile(cfg.compile, device, cfg.autocast_bf16)
        """How the update runs (:data:`UPDATE_KINDS`; ``cfg.compile`` resolved on ``device``)."""
        self.compiled = self.update_kind != "eager"
        """Whether the update runs other than eagerly."""
        self._target_forward: Callable[..., torch.Tensor] = self.target
        self._loss: Callable[..., tuple[torch.Tensor, torch.Tensor]] = _online_loss
        self._graphs: GraphedPasses | None = None
        if self.update_kind == "graphs":
            self._graphs = GraphedPasses(self.online, self.target, _online_loss)
            self._target_forward = self._graphs.target_forward
        elif self.update_kind == "inductor":
            mode = "reduce-overhead" if device.type == "cuda" else None
            self._target_forward = torch.compile(self.target, mode=mode, dynamic=False)
            self._loss = torch.compile(_online_loss, mode=mode, dynamic=False)

    def update(self, batch: Mapping[str, Any]) -> UpdateStats:
        """One gradient step on a batch from ``ReplayBuffer.sample``; returns its
        statistics (read lazily: :class:`UpdateStats`).

        ``reward`` is ``[B, O]`` (the run's O objectives); ``discount`` is ``[B, O]``
        (γ_i^m per objective, as the replay gives it) or ``[B]`` (the same for every
        objective).
        """
        cfg, dev = self.cfg, self.device
        obs = to_tensors(batch["obs"], dev)
        next_obs = to_tensors(batch["next_obs"], dev)
        action_B = torch.as_tensor(batch["action"], device=dev)
        reward_BO = torch.as_tensor(batch["reward"], device=dev)
        discount_BO = torch.as_tensor(batch["discount"], device=dev)
        if discount_BO.ndim == 1:  # one discount for every objective
            discount_BO = discount_BO[:, None].expand(-1, reward_BO.shape[1])
        B, H = action_B.shape[0], self.agent.num_heads
        N, Np, K = cfg.num_tau_samples, cfg.num_tau_prime_samples, cfg.num_quantiles
        # τ groups: one shared set for every head, or one per head (Ensemble-IQN's heads
        # each see their own τ samples, so they are not copies of one estimator).
        G = H if self.agent.spec.own_taus else 1
        taus_BGN = torch.rand(B, G, N, generator=self.tau_generator, device=dev)
        taus_prime_BGNp = torch.rand(B, G, Np, generator=self.tau_generator, device=dev)
        if self.update_kind == "inductor" and dev.type == "cuda":
            torch.compiler.cudagraph_mark_step_begin()  # last update's graph outputs are free

        with torch.no_grad(), self._autocast():
            # One target-network pass: N' sampled τ' for the loss + the fixed K grid for
            # the target rule (argmax / optimal subsets); the encoder runs once.
            taus_next = torch.cat([taus_prime_BGNp.reshape(B, G * Np), self.grid_K.expand(B, K)], 1)
            next_BHTA = self._run(self._target_forward, next_obs, taus_next).float()
            next_BHNpA = _own_group(next_BHTA[:, :, : G * Np], G)
            next_grid_BHKA = next_BHTA[:, :, G * Np :]
            subsets = self.agent.subsets
            if subsets is not None:
                subsets.observe(next_grid_BHKA)  # running scale (scaled normalisation)
            # The subsets the target rule bootstrapped from (None when it made none).
            next_action_BH, target_subsets = self.agent.target_actions_and_subsets(next_grid_BHKA)
            index = next_action_BH[:, :, None, None].expand(B, H, Np, 1)
            next_BHNp = next_BHNpA.gather(3, index).squeeze(3)
            reward_BH = self.agent.head_rewards(reward_BO)
            discount_BH = self.agent.head_discounts(discount_BO)
            target_BHNp = reward_BH[:, :, None] + discount_BH[:, :, None] * next_BHNp

        if self._graphs is not None:  # forward, loss and backward in one replay
            loss, pred_BHN = self._graphs.loss_and_backward(
                obs, taus_BGN, action_B, target_BHNp, cfg.kappa
            )
        else:
            loss, pred_BHN = self._run(
                self._loss, self.online, obs, taus_BGN, action_B, target_BHNp, cfg.kappa,
                cfg.autocast_bf16,
            )  # fmt: skip
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
        if cfg.grad_clip_norm > 0:
            torch.nn.utils.clip_grad_norm_(self.online.parameters(), cfg.grad_clip_norm)
        self.optimizer.step()
        if self.update_kind == "inductor":  # gradients in CUDA-graph-tree memory: drop them
            self.optimizer.zero_grad(set_to_none=True)
        self.updates += 1
        if self.updates % cfg.target_update_interval == 0:
            self.sync_target()
        stats = {"loss": loss.detach(), "q_mean": pred_BHN.detach().mean()}
        if target_subsets is not None:
            # How much each preorder level pruned the target batch (mean |S_r|).
            sizes = target_subsets.size_tensors()
            stats.update({f"subset_size/{k}": v for k, v in sizes.items()})
        return UpdateStats(stats)

    def _run(self, fn: Callable[..., Any], *args: Any) -> Any:
        """``fn(*args)``; a compiled ``fn`` that fails to build is one line naming the fix."""
        if self.update_kind != "inductor":
            return fn(*args)
        try:
            return fn(*args)
        except Exception as exc:  # torch._dynamo.exc.BackendCompilerFailed and kin
            if "dynamo" not in type(exc).__module__ and "inductor" not in type(exc).__module__:
                raise
            line = next((ln for ln in str(exc).splitlines() if ln.strip()), type(exc).__name__)
            raise PriqnError(
                f"learner.compile: torch.compile failed on {self.device.type} ({line}); "
                "set learner.compile = 'off'"
            ) from exc

    def _autocast(self) -> Any:
        """bfloat16 autocast of the forward passes when ``autocast_bf16`` is set."""
        return torch.autocast(self.device.type, torch.bfloat16, enabled=self.cfg.autocast_bf16)

    def sync_target(self) -> None:
        """Hard copy online → target."""
        self.target.load_state_dict(self.online.state_dict())

    def state_dict(self) -> dict[str, Any]:
        return {
            "online": self.online.state_dict(),
            "target": self.target.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "updates": self.updates,
            "tau_generator": self.tau_generator.get_state(),
            "agent": self.agent.state_dict(),
        }

    def load_state_dict(self, state: Mapping[str, Any]) -> bool:
        """Restore :meth:`state_dict`. Returns False when the τ stream could not go on.

        A generator's state is a CPU byte tensor whatever its device (a checkpoint loaded
        with ``map_location="cuda"`` moves it: it goes back to the CPU here). CPU and CUDA
        generators keep different states (Mersenne Twister, 5056 bytes; Philox, 16), so a
        state from the other device type cannot continue: the generator is then seeded
        from that state's bytes (deterministic) and this returns False. Such a resume
        cannot be bit-identical anyway: the two devices' float arithmetic differs.
        """
        self.online.load_state_dict(state["online"])
        self.target.load_state_dict(state["target"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.updates = int(state["updates"])
        self.agent.load_state_dict(state.get("agent", {}))
        tau_state = state["tau_generator"].cpu()
        if tau_state.numel() == self.tau_generator.get_state().numel():
            self.tau_generator.set_state(tau_state)
            return True
        digest = hashlib.sha256(tau_state.numpy().tobytes()).digest()
        self.tau_generator.manual_seed(int.from_bytes(digest[:8], "little") >> 1)
        return False
