"""Hyperparameters of the six algorithms: one frozen dataclass, validated once, and named presets.

SHAC defaults are DiffRL's for the Ant (Xu et al., 2022); SAPO defaults are Mineral's
``DFlexAntSAPO`` (Xing et al., 2025; the code the ARE paper's experiments used); the TD-lambda
settings are the ARE paper's (Section IV): lambda = 0.95 for both actor and critic, adaptive
lambda = sigmoid(phi) trained by AdamW (lr 5e-4, betas (0.7, 0.95)) with one full-batch update
per epoch (b_lambda = 1, m_lambda = 1).

Every field's ``help`` is its documentation and the ``--help`` text of its command-line flag.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field
from typing import Literal, get_args, get_type_hints

REMOVED_HYPERPARAMETERS = frozenset({"extra"})  # in config.json files of older runs; never read

# Upper bounds of the counts, so that a value no run can mean (or no machine can hold) is refused when
# the configuration is made, not hours into training; the harness's flags use the same ones.
MAX_ENVS = 65_536
MAX_HORIZON = 10_000
MAX_EPOCHS = 10**6
MAX_WIDTH = 8192  # a hidden layer's width: a square float32 layer of 8192 holds 256 MiB before Adam's two states
MAX_LAYERS = 32
MAX_CRITICS = 16  # an ensemble of critics; the paper's SAPO uses 2
MAX_ITERATIONS = 1000  # critic or lambda passes per epoch (DiffRL's critic makes 16)

#: the six algorithms, declared once: a family (SHAC, SAPO) and its actor return (h-step, TD-lambda
#: with a fixed lambda, TD-lambda with an adaptive one)
AlgoName = Literal["shac", "shac-tdfixed", "shac-tdadpt", "sapo", "sapo-tdfixed", "sapo-tdadpt"]
ALGORITHMS: tuple[str, ...] = get_args(AlgoName)


def _doc(default, help: str):
    """A dataclass field whose documentation travels with it (read by the CLI)."""
    return field(default=default, metadata={"help": help})


@dataclass(frozen=True)
class AlgoConfig:
    algo: AlgoName = _doc("shac", "algorithm preset these settings started from")
    # -- rollout / returns -------------------------------------------------------------
    num_envs: int = _doc(64, "N: parallel environments per epoch")
    horizon: int = _doc(32, "h: control steps per window; the graph is cut at every window start")
    gamma: float = _doc(0.99, "discount factor, in (0, 1]")
    lam: float = _doc(
        0.95, "TD-lambda of the critic targets; also the actor's lambda (TDFixed) or its start value (TDAdpt)"
    )
    actor_return: Literal["h_step", "td_lambda"] = _doc(
        "h_step", "actor return: h_step (eq. 9, SHAC/SAPO) or td_lambda (eq. 12, the TD variants)"
    )
    adaptive_lambda: bool = _doc(False, "learn lambda = sigmoid(phi) online on eq. 15 (TDAdpt)")
    soft: bool = _doc(
        False, "SAPO: entropy bonus in the return and the critic targets, squashed Gaussian, learned temperature"
    )
    # -- networks ----------------------------------------------------------------------
    actor_hidden: tuple[int, ...] = _doc((128, 64, 32), "hidden layer widths of the actor MLP")
    critic_hidden: tuple[int, ...] = _doc((64, 64), "hidden layer widths of the critic MLP")
    network_style: Literal["diffrl", "mineral"] = _doc(
        "diffrl",
        "diffrl: Linear-ELU-LayerNorm, default actor init, orthogonal(sqrt 2) critic; "
        "mineral: Linear-LayerNorm-SiLU, orthogonal(1) weights and zero biases everywhere",
    )
    obs_norm: bool = _doc(True, "normalise observations by running statistics (frozen during each rollout)")
    num_critics: int = _doc(1, "critics in the ensemble (SAPO: 2; min for targets, mean for the actor bootstrap)")
    target_critic_alpha: float | None = _doc(
        0.2, "Polyak weight kept on the old target critic, in [0, 1]; None = no target critic"
    )
    # -- optimisation ------------------------------------------------------------------
    optimizer: Literal["adam", "adamw"] = _doc("adam", "optimiser of actor and critic")
    weight_decay: float = _doc(0.0, "weight decay of actor and critic (AdamW's torch default 0.01 made explicit)")
    actor_lr: float = _doc(2e-3, "actor learning rate at epoch 0")
    critic_lr: float = _doc(2e-3, "critic learning rate at epoch 0")
    lr_schedule: Literal["linear", "constant"] = _doc(
        "linear", "linear: actor and critic rates decay to min_lr at max_epochs; constant: no decay"
    )
    min_lr: float = _doc(1e-5, "learning rate reached at max_epochs by the linear schedule")
    betas: tuple[float, float] = _doc((0.7, 0.95), "Adam(W) betas of actor and critic")
    actor_grad_clip: float = _doc(1.0, "max global norm of the actor gradient")
    critic_grad_clip: float = _doc(1.0, "max global norm of the critic gradient")
    critic_iterations: int = _doc(16, "m_critic: passes over the window's data per epoch")
    critic_minibatches: int = _doc(4, "b_critic: minibatches per pass")
    max_epochs: int = _doc(0, "end of the linear learning-rate decay; 0 = the run's number of epochs")
    # -- adaptive lambda (TDAdpt) ------------------------------------------------------
    lambda_lr: float = _doc(5e-4, "AdamW learning rate of phi (lambda = sigmoid(phi))")
    lambda_betas: tuple[float, float] = _doc((0.7, 0.95), "AdamW betas of phi")
    lambda_weight_decay: float = _doc(
        0.0, "AdamW weight decay of phi; 0 because eq. 15 has no regulariser (torch's default 0.01 pulls phi to 0)"
    )
    lambda_batches: int = _doc(1, "b_lambda: env groups per lambda iteration")
    lambda_iterations: float = _doc(1.0, "m_lambda: lambda iterations per epoch; 1/k = one every k-th epoch")
    # -- SAPO temperature ----------------------------------------------------------------
    init_alpha: float = _doc(1.0, "initial entropy temperature alpha (SAPO)")
    alpha_lr: float = _doc(5e-3, "AdamW learning rate of log alpha")
    alpha_weight_decay: float = _doc(0.01, "AdamW weight decay of log alpha (Mineral runs with torch's default)")
    alpha_grad_clip: float = _doc(0.5, "max gradient norm of the temperature update")
    target_entropy_per_dim: float = _doc(-0.5, "target entropy = this * |A| (SAPO)")
    # -- diagnostics ---------------------------------------------------------------------
    grad_var_groups: int = _doc(4, "K env groups for the actor-gradient variance (must divide num_envs)")
    max_grad_norm_skip: float = _doc(1e6, "an actor or critic update whose gradient norm exceeds this is skipped")

    def __post_init__(self) -> None:
        problems = _problems(self)
        if problems:
            raise ValueError("; ".join(problems))

    def replace(self, **changes) -> AlgoConfig:
        """A copy with ``changes`` applied (validated again)."""
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> AlgoConfig:
        """Inverse of :meth:`as_dict` after a JSON round trip (lists back to tuples)."""
        known = {f.name for f in dataclasses.fields(cls)}
        data = {k: v for k, v in data.items() if k not in REMOVED_HYPERPARAMETERS}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown hyperparameter(s): {', '.join(unknown)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})

    @classmethod
    def help(cls, name: str) -> str:
        return next(f.metadata.get("help", "") for f in dataclasses.fields(cls) if f.name == name)


@functools.cache
def _type_hints() -> dict:
    """AlgoConfig's field types, resolved once (the annotations are strings; resolving them is slow)."""
    return get_type_hints(AlgoConfig)


def _problems(cfg: AlgoConfig) -> list[str]:
    """Every range and type violation of ``cfg``, each as one phrase naming the valid range."""
    problems = []
    hints = _type_hints()
    for f in dataclasses.fields(cfg):
        value, hint = getattr(cfg, f.name), hints[f.name]
        choices = get_args(hint) if getattr(hint, "__origin__", None) is Literal else None
        if choices and value not in choices:
            problems.append(f"{f.name} must be one of {', '.join(choices)}, got {value!r}")
        elif hint is bool and not isinstance(value, bool):
            problems.append(f"{f.name} must be true or false, got {value!r}")
        elif hint is int and (isinstance(value, bool) or not isinstance(value, int)):
            problems.append(f"{f.name} must be an integer, got {value!r}")
        elif hint in (float, float | None) and value is not None:
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                problems.append(f"{f.name} must be a finite number, got {value!r}")
    if problems:
        return problems  # ranges below assume the types are right

    def need(ok: bool, text: str) -> None:
        if not ok:
            problems.append(text)

    need(1 <= cfg.num_envs <= MAX_ENVS, f"num_envs must be in [1, {MAX_ENVS}], got {cfg.num_envs}")
    need(1 <= cfg.horizon <= MAX_HORIZON, f"horizon must be in [1, {MAX_HORIZON}], got {cfg.horizon}")
    need(0.0 < cfg.gamma <= 1.0, f"gamma must be in (0, 1], got {cfg.gamma}")
    if cfg.adaptive_lambda:
        need(0.0 < cfg.lam < 1.0, f"lam must be in (0, 1) with adaptive lambda, got {cfg.lam}")
    else:
        need(0.0 <= cfg.lam <= 1.0, f"lam must be in [0, 1], got {cfg.lam}")
    widths = cfg.actor_hidden + cfg.critic_hidden
    need(all(1 <= w <= MAX_WIDTH for w in widths), f"hidden widths must be in [1, {MAX_WIDTH}], got {widths}")
    layers = max(len(cfg.actor_hidden), len(cfg.critic_hidden))
    need(layers <= MAX_LAYERS, f"at most {MAX_LAYERS} hidden layers, got {layers}")
    need(1 <= cfg.num_critics <= MAX_CRITICS, f"num_critics must be in [1, {MAX_CRITICS}], got {cfg.num_critics}")
    if cfg.target_critic_alpha is not None:
        alpha = cfg.target_critic_alpha
        need(0.0 <= alpha <= 1.0, f"target_critic_alpha must be in [0, 1], got {alpha}")
    for name in ("actor_lr", "critic_lr", "lambda_lr", "alpha_lr", "init_alpha"):
        need(getattr(cfg, name) > 0.0, f"{name} must be > 0, got {getattr(cfg, name)}")
    for name in ("actor_grad_clip", "critic_grad_clip", "alpha_grad_clip", "max_grad_norm_skip"):
        need(getattr(cfg, name) > 0.0, f"{name} must be > 0, got {getattr(cfg, name)}")
    for name in ("weight_decay", "lambda_weight_decay", "alpha_weight_decay"):
        need(getattr(cfg, name) >= 0.0, f"{name} must be >= 0, got {getattr(cfg, name)}")
    need(0.0 <= cfg.min_lr <= min(cfg.actor_lr, cfg.critic_lr), "min_lr must be in [0, min(actor_lr, critic_lr)]")
    for name in ("betas", "lambda_betas"):
        need(all(0.0 <= b < 1.0 for b in getattr(cfg, name)), f"{name} must lie in [0, 1), got {getattr(cfg, name)}")
    need(
        1 <= cfg.critic_iterations <= MAX_ITERATIONS,
        f"critic_iterations (m_critic) must be in [1, {MAX_ITERATIONS}] (0 never trains the critic), "
        f"got {cfg.critic_iterations}",
    )
    # a tanh-squashed action's entropy per dimension is at most ln 2 (uniform on [-1, 1]); far below, the
    # target asks for a standard deviation float32 cannot hold
    target = cfg.target_entropy_per_dim
    need(-50.0 <= target < math.log(2.0), f"target_entropy_per_dim must be in [-50, ln 2), got {target}")
    # more minibatches than samples (envs x h), or batches than envs, would silently make fewer
    samples = cfg.num_envs * cfg.horizon
    need(
        1 <= cfg.critic_minibatches <= samples,
        f"critic_minibatches must be in [1, num_envs x horizon = {samples}], got {cfg.critic_minibatches}",
    )
    need(
        1 <= cfg.lambda_batches <= cfg.num_envs,
        f"lambda_batches (env groups) must be in [1, num_envs = {cfg.num_envs}], got {cfg.lambda_batches}",
    )
    need(0 <= cfg.max_epochs <= MAX_EPOCHS, f"max_epochs must be in [0, {MAX_EPOCHS}], got {cfg.max_epochs}")
    m = cfg.lambda_iterations
    need(0.0 < m <= MAX_ITERATIONS, f"lambda_iterations (m_lambda) must be in (0, {MAX_ITERATIONS}], got {m}")
    if 0.0 < m < 1.0:
        need(float(1.0 / m).is_integer(), "a fractional lambda_iterations must be 1/k (0.5, 0.25, ...)")
    elif m >= 1.0:
        need(float(m).is_integer(), "lambda_iterations >= 1 must be an integer")
    need(
        cfg.grad_var_groups >= 2 and cfg.num_envs % cfg.grad_var_groups == 0,
        f"grad_var_groups must be >= 2 and divide num_envs={cfg.num_envs}",
    )
    return problems


def _shac(**changes) -> AlgoConfig:
    return AlgoConfig(algo="shac").replace(**changes)


def _sapo(**changes) -> AlgoConfig:
    base = AlgoConfig(
        algo="sapo",
        soft=True,
        network_style="mineral",
        num_critics=2,
        target_critic_alpha=None,
        optimizer="adamw",
        weight_decay=0.01,
        actor_lr=2e-3,
        critic_lr=5e-4,
        actor_grad_clip=0.5,
        critic_grad_clip=0.5,
    )
    return base.replace(**changes)


#: the actor return of each variant suffix (none: SHAC's and SAPO's own h-step return, eq. 10)
_VARIANTS = {
    "": {},
    "tdfixed": {"actor_return": "td_lambda"},
    "tdadpt": {"actor_return": "td_lambda", "adaptive_lambda": True},
}


def preset(name: str) -> AlgoConfig:
    """The settings of algorithm ``name`` (one of :data:`ALGORITHMS`)."""
    if name not in ALGORITHMS:
        raise KeyError(f"unknown algorithm {name!r}; choose from: {', '.join(ALGORITHMS)}")
    family, _, variant = name.partition("-")
    return (_shac if family == "shac" else _sapo)(algo=name, **_VARIANTS[variant])
