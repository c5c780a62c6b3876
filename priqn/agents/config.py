"""The agents' facts that torch-free code needs: configs, the agent interface, option names.

``AgentConfig`` / ``NetworkConfig`` / ``LearnerConfig`` (the ``[agent]``, ``[network]`` and
``[learner]`` tables of a TrainConfig); the agent interface (:class:`AgentSpec`: display
name, heads and the three rule functions; :func:`resolve_agent` finds the declaration an
``agent.name`` names: shipped, ``package.module:NAME`` or entry point ``priqn.agents``)
and the names of the Pr-IQN options. At import it loads neither torch nor another module of
this package (whose ``__init__`` is lazy), so :mod:`priqn.agents.preorder`,
:mod:`priqn.agents.labels`, the sweep's experiment files and the analysis can read these
facts without importing torch or the agents' networks.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, Protocol

from priqn.errors import PriqnError
from priqn.objectives import NUM_OBJECTIVES
from priqn.plugins import import_path, import_plugin

NORMALISATIONS: tuple[str, ...] = ("zscore", "scaled")
"""Quantile normalisations of the Pr-IQN comparators (docs/preorder.md)."""
COMPARATOR_NAMES: dict[str, str] = {"qd": "QD", "mv": "MV", "cvar": "CVaR", "fsd": "FSD"}
"""Comparator name → its display name in tables (the functions, in the same order:
``priqn.agents.comparators.COMPARATOR_FUNCTIONS``)."""
PREORDER_PRESETS: tuple[str, ...] = ("total", "partial", "right-of-way")
"""Named preorders (``priqn/presets/<name>.toml``); any other value is a TOML path."""
COMPILE_MODES: tuple[str, ...] = ("auto", "graphs", "on", "off")
"""Values of ``learner.compile`` (``priqn.agents.learner.resolve_compile``)."""


@dataclasses.dataclass(frozen=True)
class AgentConfig:
    """Which agent, and the options of the preordered one."""

    name: str = "pr-iqn"
    """Agent: iqn, ensemble-iqn, ma-iqn, pr-iqn, your own as 'package.module:NAME', or an installed entry point of group priqn.agents (docs/your-own-agent.md)."""
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
    """How the update runs: auto (CUDA graphs on CUDA, eager elsewhere), graphs (the update's network passes and backward replayed from CUDA graphs: the eager kernels without their launch cost; CUDA only), on (torch.compile; CUDA graphs on CUDA), or off (the eager update, bit for bit). docs/implementation-details.md §12."""

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

    def gammas(self, num_objectives: int) -> tuple[float, ...]:
        """γ per objective of a run with ``num_objectives`` objectives (declared order)."""
        if isinstance(self.gamma, tuple):
            if len(self.gamma) != num_objectives:
                raise ValueError(
                    f"gamma: expected one number or {num_objectives} numbers (one per objective)"
                )
            return tuple(float(g) for g in self.gamma)
        return (float(self.gamma),) * num_objectives


# ----------------------------------------------------------------------------- the agent interface
# An agent is one IQN learner (network, τ sampling, quantile Huber loss, Adam) with H
# heads and three rules; docs/your-own-agent.md. Tensors are torch tensors (typed Any
# here: this module stays torch-free), named by shape as in priqn.agents.network.


class RewardRule(Protocol):
    """What each head learns: ``rule(rewards_BO, weights_O, num_heads) -> rewards_BH``.

    ``rewards_BO``: the reward vectors (the run's O objectives, ``env.objectives`` order);
    ``weights_O``: the weighted-sum weights (``agent.reward_weights`` or the scheme's)."""

    def __call__(self, rewards_BO: Any, weights_O: Any, num_heads: int) -> Any: ...


class ActingRule(Protocol):
    """Fixed-grid quantiles of the current states → one action each (int64 ``[B]``):
    ``rule(quantiles_BHKA, subsets, u_B, weights_O)``. ``subsets``: ``quantiles_BNKA ->
    OptimalSubsets`` (``per_objective [B, N, A]``, ``leaf [B, A]``) for an agent that
    ``uses_preorder``, else None; ``u_B`` ∈ [0, 1): one uniform draw per state, the only
    randomness a rule may use."""

    def __call__(self, quantiles_BHKA: Any, subsets: Any, u_B: Any, weights_O: Any) -> Any: ...


class TargetRule(Protocol):
    """Fixed-grid quantiles of the next states → the action each head bootstraps from
    (int64 ``[B, H]``): ``rule(next_quantiles_BHKA, subsets)``."""

    def __call__(self, next_quantiles_BHKA: Any, subsets: Any) -> Any: ...


class ScalarValue(Protocol):
    """The scalar return distribution a greedy acting rule ranks actions by:
    ``value(quantiles_BHKA, weights_O) -> values_BKA`` (its mean's argmax is the rule's action)."""

    def __call__(self, quantiles_BHKA: Any, weights_O: Any) -> Any: ...


def rule_name(rule: Any) -> str:
    """A rule's name in logs, docs and comparisons: the ``rule_name`` priqn's own rules carry
    (``argmax``, ``optimal-subset``), else ``module:qualified name``."""
    name = getattr(rule, "rule_name", None)
    if isinstance(name, str):
        return name
    return f"{getattr(rule, '__module__', '?')}:{getattr(rule, '__qualname__', repr(rule))}"


@dataclasses.dataclass(frozen=True)
class AgentSpec:
    """What one agent is: its heads, its three rules (the functions themselves) and how
    tables name it. priqn builds every agent, shipped or plug-in, from one of these
    (:mod:`priqn.agents.build`); docs/your-own-agent.md."""

    display_name: str
    """Name in tables and labels (``IQN``, ``Pr-IQN``)."""
    num_heads: int
    """Quantile heads H of the network."""
    reward: RewardRule
    """How rewards reach the heads (:class:`RewardRule`)."""
    act: ActingRule
    """How an action is chosen from the heads (:class:`ActingRule`)."""
    target: TargetRule
    """Which next action each head bootstraps from (:class:`TargetRule`)."""
    per_objective_heads: bool = False
    """Head h learns objective h alone and bootstraps with its γ_h (needs H = O); False:
    the heads learn returns that mix objectives, so the run needs one γ for all."""
    uses_preorder: bool = False
    """Acts on optimal subsets of ``agent.preorder``: the agent's rules get a ``subsets``
    function (Algorithm 1 with ``agent.comparator``, ``eps``, ``normalisation``), and
    labels and run names show those options."""
    scalar_value: ScalarValue | None = None
    """The scalar return distribution :attr:`act` ranks actions by, for the near-greedy
    control (docs/evaluation.md); None: the control does not apply."""
    own_taus: bool = False
    """Each head draws its own τ samples in the loss (Ensemble-IQN), not one shared set."""

    def __post_init__(self) -> None:
        if not isinstance(self.num_heads, int) or self.num_heads < 1:
            raise PriqnError(f"agent {self.display_name!r}: num_heads must be a positive integer")
        for field in ("reward", "act", "target"):
            if not callable(getattr(self, field)):
                raise PriqnError(f"agent {self.display_name!r}: {field} must be a function")

    @property
    def reward_rule(self) -> str:
        """:func:`rule_name` of :attr:`reward` (``weighted-sum``, ``per-objective``)."""
        return rule_name(self.reward)

    @property
    def acting_rule(self) -> str:
        """:func:`rule_name` of :attr:`act` (``argmax``, ``leaf-uniform``, ...)."""
        return rule_name(self.act)

    @property
    def target_rule(self) -> str:
        """:func:`rule_name` of :attr:`target` (``own-argmax``, ``optimal-subset``)."""
        return rule_name(self.target)


AgentDeclaration = AgentSpec | Callable[[AgentConfig, int], AgentSpec]
"""What ``agent.name`` names: an :class:`AgentSpec`, or ``fn(agent_cfg, num_objectives)``
returning one (heads and rules may follow the config and the run's objective count)."""

ENTRY_POINT_GROUP = "priqn.agents"
"""Entry-point group under which other packages register agent declarations."""

SHIPPED_AGENTS: dict[str, str] = {
    "iqn": "priqn.agents.shipped:iqn",
    "ensemble-iqn": "priqn.agents.shipped:ensemble_iqn",
    "ma-iqn": "priqn.agents.shipped:ma_iqn",
    "pr-iqn": "priqn.agents.shipped:pr_iqn",
}
"""The agents priqn ships: name → its declaration, by path (written like an entry point,
and a path rather than an import so this module stays torch-free:
``priqn/agents/shipped.py``). Table order."""


def resolve_agent(name: str, where: str = "agent.name") -> AgentDeclaration:
    """The declaration ``agent.name`` names, resolved in this order: a shipped name
    (:data:`SHIPPED_AGENTS`), ``package.module:NAME`` (your module), or an entry point of
    group ``priqn.agents`` (an installed package). Unknown names are one line listing the
    known ones."""
    if not isinstance(name, str) or not name:
        raise PriqnError(f"{where}: expected an agent name or 'package.module:NAME', got {name!r}")
    if name in SHIPPED_AGENTS:
        obj = import_path(SHIPPED_AGENTS[name], where)
    else:
        obj = import_plugin(
            name, SHIPPED_AGENTS, _entry_points(), where, "agent", "valid",
            "priqn.agents.config.AgentSpec",
        )  # fmt: skip
    if not (isinstance(obj, AgentSpec) or callable(obj)):
        raise PriqnError(
            f"{where}: {name!r} is a {type(obj).__name__}, expected an AgentSpec or a function "
            "(agent_cfg, num_objectives) -> AgentSpec"
        )
    return obj


def resolve_spec(
    cfg: AgentConfig, num_objectives: int = NUM_OBJECTIVES, where: str = "agent.name"
) -> AgentSpec:
    """The :class:`AgentSpec` of ``cfg.name`` under ``cfg`` for a run with
    ``num_objectives`` objectives (:func:`resolve_agent`; one-line errors naming ``where``)."""
    declared = resolve_agent(cfg.name, where)
    spec = declared if isinstance(declared, AgentSpec) else declared(cfg, num_objectives)
    if not isinstance(spec, AgentSpec):
        raise PriqnError(
            f"{where}: {cfg.name!r} gave a {type(spec).__name__}, expected an AgentSpec"
        )
    if spec.per_objective_heads and spec.num_heads != num_objectives:
        raise PriqnError(
            f"{where}: {cfg.name!r} has per-objective heads but {spec.num_heads} heads "
            f"for {num_objectives} objectives"
        )
    return spec


def agent_spec(
    name: str, cfg: AgentConfig | None = None, num_objectives: int = NUM_OBJECTIVES
) -> AgentSpec | None:
    """The spec of agent ``name`` (under ``cfg``, else the defaults) for labels and tables,
    which read agent names from data files: shipped names and installed entry points
    only. None for unknown names and for ``package.module:NAME`` paths (reading a CSV or
    JSON never imports a module it names; such an agent's tables show its path)."""
    if ":" in name or (name not in SHIPPED_AGENTS and name not in _entry_points()):
        return None
    return resolve_spec(cfg or AgentConfig(name=name), num_objectives)


def has_scalar_value(name: str) -> bool:
    """Agent ``name`` acts greedily on one scalar value (IQN, Ensemble-IQN, MA-IQN), so the
    near-greedy acting-randomness control applies to it (docs/evaluation.md)."""
    spec = agent_spec(name)
    return spec is not None and spec.scalar_value is not None


@functools.cache
def _entry_points() -> dict[str, Any]:
    """Installed declarations of group ``priqn.agents``, by name (read once per process)."""
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}
