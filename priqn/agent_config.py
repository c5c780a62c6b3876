"""The agents' facts that torch-free code needs: configs, specs, comparator and preset names.

``AgentConfig`` / ``NetworkConfig`` / ``LearnerConfig`` (the ``[agent]``, ``[network]`` and
``[learner]`` tables of a TrainConfig), what each agent is (:data:`AGENT_SPECS`: display
name, heads, rule names) and the names of the Pr-IQN options. It lives outside
:mod:`priqn.agents` so that :mod:`priqn.preorder`, :mod:`priqn.labels`, the sweep's
experiment files and the analysis can read these facts without importing torch or the
agents package (which itself imports the preorder and the labels).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from priqn.objectives import NUM_OBJECTIVES

NORMALISATIONS: tuple[str, ...] = ("zscore", "scaled")
"""Quantile normalisations of the Pr-IQN comparators (docs/preorder.md)."""
COMPARATOR_NAMES: dict[str, str] = {"qd": "QD", "mv": "MV", "cvar": "CVaR", "fsd": "FSD"}
"""Comparator name → its display name in tables (the functions, in the same order:
``priqn.preorder.COMPARATOR_FUNCTIONS``)."""
PREORDER_PRESETS: tuple[str, ...] = ("total", "partial", "right-of-way")
"""Named preorders (``priqn/presets/<name>.toml``); any other value is a TOML path."""
COMPILE_MODES: tuple[str, ...] = ("auto", "on", "off")
"""Values of ``learner.compile`` (``priqn.agents.learner.resolve_compile``)."""


@dataclasses.dataclass(frozen=True)
class AgentConfig:
    """Which agent, and the options of the preordered one."""

    name: str = "pr-iqn"
    """Agent: iqn, ensemble-iqn, ma-iqn or pr-iqn."""
    comparator: str = "qd"
    """Pr-IQN comparator for one objective: qd (quantile dominance, the paper), mv (mean-variance), cvar, or fsd (ε-first-order stochastic dominance)."""
    normalisation: str = "zscore"
    """Pr-IQN quantile normalisation: zscore (the paper: per-state spread) or scaled (spread floored by a per-objective running scale; docs/preorder.md)."""
    scale_fraction: float = 1.0
    """Scaled normalisation: spread floor = this fraction of the objective's running typical spread [-]."""
    scale_momentum: float = 0.01
    """Scaled normalisation: weight of each learner batch in the running spread average [-]."""
    eps: float | tuple[float, ...] = 0.2
    """Pr-IQN tolerance ε: one number for all objectives or one per objective (env.objectives order)."""
    preorder: str = "total"
    """Pr-IQN preorder: 'total' (the chain of env.objectives in their order: safety>risk>lane>progress>comfort by default), 'partial', 'right-of-way', or a TOML file."""
    train_preorder: bool = True
    """Pr-IQN Eq. 6: head h bootstraps from argmax over its optimal subset S_h (off: all actions)."""
    reward_scheme: str = "hln-2-task"
    """Weighted-sum scheme of IQN / Ensemble / MA-IQN: hln-2-task (the sensitivity check's best), hln-2, hln-4 or halving (priqn.agents.scalarise; docs/implementation-details.md)."""
    reward_weights: tuple[float, ...] | None = None
    """Explicit weights Σ w_i r_i in env.objectives order, overriding reward_scheme (unset = the scheme's, resolved for the run's episode length, discount and safety penalty)."""
    ensemble_heads: int = 5
    """Heads of ensemble-iqn (the paper matches the number of objectives)."""

    def __post_init__(self) -> None:
        # Lengths against the run's objectives: check_lengths (TrainConfig, make_agent).
        if self.reward_weights is not None and not self.reward_weights:
            raise ValueError("reward_weights: expected one number per objective")
        if isinstance(self.eps, tuple):
            if not self.eps:
                raise ValueError("eps: expected one number or one per objective")
            if min(self.eps) < 0:
                raise ValueError("eps: expected non-negative tolerances")
        elif self.eps < 0:
            raise ValueError("eps: expected a non-negative tolerance")
        if self.normalisation not in NORMALISATIONS:
            raise ValueError(
                f"normalisation: unknown {self.normalisation!r} (valid: {', '.join(NORMALISATIONS)})"
            )
        if not self.scale_fraction >= 0 or not 0 < self.scale_momentum <= 1:
            raise ValueError("scale_fraction >= 0 and scale_momentum in (0, 1] expected")
        if self.ensemble_heads < 1:
            raise ValueError("ensemble_heads: expected a positive integer")

    def check_lengths(self, objectives: tuple[str, ...]) -> None:
        """Per-objective values (``eps``, ``reward_weights``) must have one entry per
        objective of the run; ValueError naming the field otherwise."""
        n = len(objectives)
        if self.reward_weights is not None and len(self.reward_weights) != n:
            raise ValueError(f"reward_weights: expected {n} numbers ({', '.join(objectives)})")
        if isinstance(self.eps, tuple) and len(self.eps) != n:
            raise ValueError(f"eps: expected one number or {n} numbers ({', '.join(objectives)})")


@dataclasses.dataclass(frozen=True)
class NetworkConfig:
    """Sizes of the encoder and the IQN heads."""

    conv_channels: tuple[int, ...] = (16, 32, 32)
    """Output channels of the three conv layers of each grid CNN (BEV and LiDAR)."""
    vector_hidden: int = 64
    """Width of the MLP layer on the vector inputs (command one-hot + kinematics)."""
    latent_dim: int = 256
    """Width of the fused latent the cosine embedding multiplies (256-512 keeps the product cheap; docs/implementation-details.md §2)."""
    num_cosines: int = 64
    """Cosines in the τ embedding cos(π i τ), i = 1..num_cosines."""
    hidden_dim: int = 256
    """Width of the hidden layer shared by all heads (after the τ product)."""
    kinematics_scale: float = 0.1
    """Factor on the kinematics vector (m/s, m/s²) before the MLP, so typical values are O(1)."""

    def __post_init__(self) -> None:
        if len(self.conv_channels) != 3 or min(self.conv_channels) < 1:
            raise ValueError("conv_channels: expected three positive integers")
        for name in ("vector_hidden", "latent_dim", "num_cosines", "hidden_dim"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected a positive integer")


@dataclasses.dataclass(frozen=True)
class LearnerConfig:
    """IQN learning hyper-parameters (names follow Dabney et al. 2018)."""

    gamma: float | tuple[float, ...] = 0.99
    """Discount γ per decision (0.5 s): one number, or one per objective (env.objectives order; the paper defines a γ_i per objective). Agents whose heads learn a weighted sum need equal values."""
    lr: float = 1e-4
    """Adam learning rate."""
    adam_eps: float = 3.125e-4
    """Adam ε (0.01 / batch 32, as Dopamine's IQN)."""
    batch_size: int = 32
    """Transitions per update."""
    num_tau_samples: int = 32
    """N: sampled τ for the online (predicted) quantiles in the loss."""
    num_tau_prime_samples: int = 32
    """N': sampled τ' for the target quantiles in the loss."""
    num_quantiles: int = 32
    """K: size of the fixed τ grid (k + 0.5)/K used for acting, targets' argmax and subsets."""
    kappa: float = 1.0
    """Huber threshold κ of the quantile Huber loss."""
    n_step: int = 3
    """n-step returns (1 = the paper's one-step TD of Eq. 7)."""
    target_update_interval: int = 1000
    """Updates between hard copies of the online network into the target network."""
    grad_clip_norm: float = 10.0
    """Clip the global gradient norm to this value (0 = no clipping)."""
    autocast_bf16: bool = False
    """Run the network's forward passes in bfloat16 autocast (loss, targets and subsets stay float32); faster on CPUs with bf16 support, see docs/implementation-details.md."""
    compile: str = "auto"
    """torch.compile the update (target forward; online forward, loss and backward; CUDA graphs on CUDA): auto (on for CUDA where Triton is installed, off on CPU, where it did not pay on this project's 2-core CPU: docs/implementation-details.md §12), on, or off (the eager update, bit for bit)."""

    def __post_init__(self) -> None:
        if self.compile not in COMPILE_MODES:
            raise ValueError(
                f"compile: unknown {self.compile!r} (valid: {', '.join(COMPILE_MODES)})"
            )
        gammas = self.gamma if isinstance(self.gamma, tuple) else (self.gamma,)
        if not gammas:  # the length against the run's objectives: TrainConfig
            raise ValueError("gamma: expected one number or one per objective")
        if not all(0.0 <= g <= 1.0 for g in gammas):
            raise ValueError("gamma: expected numbers in [0, 1]")
        for name in (
            "batch_size",
            "num_tau_samples",
            "num_tau_prime_samples",
            "num_quantiles",
            "n_step",
            "target_update_interval",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected a positive integer")
        if self.kappa <= 0 or self.lr <= 0:
            raise ValueError("kappa and lr: expected positive numbers")

    @property
    def gamma_5(self) -> tuple[float, ...]:
        """γ per objective of the default list (:func:`gammas` for any list)."""
        return self.gammas(NUM_OBJECTIVES)

    def gammas(self, num_objectives: int) -> tuple[float, ...]:
        """γ per objective of a run with ``num_objectives`` objectives (declared order)."""
        if isinstance(self.gamma, tuple):
            if len(self.gamma) != num_objectives:
                raise ValueError(
                    f"gamma: expected one number or {num_objectives} numbers (one per objective)"
                )
            return tuple(float(g) for g in self.gamma)
        return (float(self.gamma),) * num_objectives


@dataclasses.dataclass(frozen=True)
class AgentSpec:
    """What one agent is: its heads, its three rule names and how tables name it."""

    display_name: str
    """Name in tables and labels (``IQN``, ``Pr-IQN``)."""
    num_heads: int
    """Quantile heads of the network."""
    reward_rule: str
    """How rewards reach the heads (``priqn.agents.rules``)."""
    acting_rule: str
    """How an action is chosen from the heads."""
    target_rule: str
    """Which next action each head bootstraps from."""
    own_taus: bool = False
    """Each head draws its own τ samples in the loss (Ensemble-IQN), not one shared set."""

    @property
    def uses_preorder(self) -> bool:
        """Acts on optimal subsets of a preorder (the Pr-IQN options apply)."""
        return self.acting_rule == "leaf-uniform"


AGENT_SPECS: dict[str, Callable[..., AgentSpec]] = {
    "iqn": lambda c, n=NUM_OBJECTIVES: AgentSpec("IQN", 1, "weighted-sum", "argmax", "own-argmax"),
    "ensemble-iqn": lambda c, n=NUM_OBJECTIVES: AgentSpec(
        "Ensemble",
        c.ensemble_heads,
        "weighted-sum",
        "argmax-mean-of-heads",
        "own-argmax",
        own_taus=True,
    ),
    "ma-iqn": lambda c, n=NUM_OBJECTIVES: AgentSpec(
        "MA-IQN", n, "per-objective", "argmax-sum-of-heads", "own-argmax"
    ),
    "pr-iqn": lambda c, n=NUM_OBJECTIVES: AgentSpec(
        "Pr-IQN",
        n,
        "per-objective",
        "leaf-uniform",
        "optimal-subset" if c.train_preorder else "own-argmax",
    ),
}
"""Agent name → its :class:`AgentSpec` given the config and the number of objectives."""


def has_scalar_value(name: str) -> bool:
    """Agent ``name`` acts greedily on one scalar value (IQN, Ensemble-IQN, MA-IQN), so the
    near-greedy acting-randomness control applies to it (docs/evaluation.md)."""
    spec = agent_spec(name)
    return spec is not None and not spec.uses_preorder


def agent_spec(
    name: str, cfg: AgentConfig | None = None, num_objectives: int = NUM_OBJECTIVES
) -> AgentSpec | None:
    """The spec of agent ``name`` (under ``cfg``, else the defaults) for a run with
    ``num_objectives`` objectives; None if unknown."""
    make = AGENT_SPECS.get(name)
    return None if make is None else make(cfg or AgentConfig(name=name), num_objectives)
