"""Hyperparameters of the six algorithms, as one small dataclass and named presets.

SHAC defaults are DiffRL's for the Ant (Xu et al., 2022); SAPO defaults follow Mineral/Rewarped
(Xing et al., 2025); the TD-lambda settings are the ARE paper's (Section IV): lambda = 0.95 for
both actor and critic, adaptive lambda = sigmoid(phi) trained by AdamW (lr 5e-4, betas
(0.7, 0.95)) with one full-batch update per epoch (b_lambda = 1, m_lambda = 1).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field


@dataclass
class AlgoConfig:
    algo: str = "shac"
    # -- rollout / returns -------------------------------------------------------------
    num_envs: int = 64  # N
    horizon: int = 32  # h: steps per window (graph cut after each)
    gamma: float = 0.99
    lam: float = 0.95  # critic TD-lambda; actor lambda for TDFixed; initial lambda for TDAdpt
    actor_return: str = "h_step"  # "h_step" (eq. 9) | "td_lambda" (eq. 12)
    adaptive_lambda: bool = False  # TDAdpt (eq. 15)
    soft: bool = False  # SAPO: entropy in the return, squashed Gaussian, learnable temperature
    # -- networks ----------------------------------------------------------------------
    actor_hidden: tuple[int, ...] = (128, 64, 32)
    critic_hidden: tuple[int, ...] = (64, 64)
    obs_norm: bool = True
    num_critics: int = 1  # SAPO: 2 (min for targets, mean for the actor bootstrap)
    target_critic_alpha: float | None = 0.2  # Polyak factor kept from the target; None = no target critic
    # -- optimisation ------------------------------------------------------------------
    optimizer: str = "adam"  # "adam" (SHAC) | "adamw" (SAPO)
    actor_lr: float = 2e-3
    critic_lr: float = 2e-3
    lr_schedule: str = "linear"  # "linear" (to min_lr at max_epochs) | "constant"
    min_lr: float = 1e-5
    betas: tuple[float, float] = (0.7, 0.95)
    actor_grad_clip: float = 1.0
    critic_grad_clip: float = 1.0
    critic_iterations: int = 16  # m_critic
    critic_minibatches: int = 4  # b_critic
    max_epochs: int = 0  # end of the linear learning-rate decay; 0 = the run's number of epochs
    # -- adaptive lambda (TDAdpt) ------------------------------------------------------
    lambda_lr: float = 5e-4
    lambda_betas: tuple[float, float] = (0.7, 0.95)
    lambda_batches: int = 1  # b_lambda: env groups per lambda iteration
    lambda_iterations: float = 1.0  # m_lambda; 0.5 = one lambda iteration every second epoch
    # -- SAPO temperature ----------------------------------------------------------------
    init_alpha: float = 1.0
    alpha_lr: float = 5e-3
    target_entropy_per_dim: float = -0.5  # target entropy = this * |A|
    # -- diagnostics ---------------------------------------------------------------------
    grad_var_groups: int = 4  # K env groups for the actor-gradient variance
    max_grad_norm_skip: float = 1e6  # an actor/critic update with a larger gradient norm is skipped

    extra: dict = field(default_factory=dict)

    def validate(self) -> AlgoConfig:
        problems = []
        if self.num_envs < 1 or self.horizon < 1:
            problems.append("num_envs and horizon must be >= 1")
        if not 0.0 < self.gamma <= 1.0:
            problems.append(f"gamma must be in (0, 1], got {self.gamma}")
        if not 0.0 < self.lam < 1.0 and not (self.lam == 1.0 and not self.adaptive_lambda):
            problems.append(f"lam must be in (0, 1) (1 allowed without adaptation), got {self.lam}")
        if self.actor_return not in ("h_step", "td_lambda"):
            problems.append(f"actor_return must be h_step or td_lambda, got {self.actor_return!r}")
        if self.optimizer not in ("adam", "adamw"):
            problems.append(f"optimizer must be adam or adamw, got {self.optimizer!r}")
        if self.lr_schedule not in ("linear", "constant"):
            problems.append(f"lr_schedule must be linear or constant, got {self.lr_schedule!r}")
        for name in ("actor_lr", "critic_lr", "lambda_lr", "alpha_lr", "actor_grad_clip", "critic_grad_clip"):
            if not getattr(self, name) > 0.0:
                problems.append(f"{name} must be > 0")
        if self.critic_iterations < 0 or self.critic_minibatches < 1 or self.lambda_batches < 1:
            problems.append("critic_iterations >= 0, critic_minibatches >= 1, lambda_batches >= 1 required")
        if self.lambda_iterations <= 0.0:
            problems.append("lambda_iterations (m_lambda) must be > 0")
        if self.lambda_iterations < 1.0 and not float(1.0 / self.lambda_iterations).is_integer():
            problems.append("a fractional lambda_iterations must be 1/k (0.5, 0.25, ...)")
        if self.grad_var_groups < 2 or self.num_envs % self.grad_var_groups:
            problems.append(f"grad_var_groups must be >= 2 and divide num_envs={self.num_envs}")
        if self.num_critics < 1:
            problems.append("num_critics must be >= 1")
        if problems:
            raise ValueError("; ".join(problems))
        return self

    def replace(self, **changes) -> AlgoConfig:
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_dict(cls, data: dict) -> AlgoConfig:
        """Inverse of ``dataclasses.asdict`` after a JSON round trip (lists back to tuples)."""
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


def _shac(**changes) -> AlgoConfig:
    return AlgoConfig(algo="shac").replace(**changes)


def _sapo(**changes) -> AlgoConfig:
    base = AlgoConfig(
        algo="sapo",
        soft=True,
        num_critics=2,
        target_critic_alpha=None,
        optimizer="adamw",
        actor_lr=2e-3,
        critic_lr=5e-4,
        actor_grad_clip=0.5,
        critic_grad_clip=0.5,
    )
    return base.replace(**changes)


PRESETS = {
    "shac": lambda: _shac(),
    "shac-tdfixed": lambda: _shac(algo="shac-tdfixed", actor_return="td_lambda"),
    "shac-tdadpt": lambda: _shac(algo="shac-tdadpt", actor_return="td_lambda", adaptive_lambda=True),
    "sapo": lambda: _sapo(),
    "sapo-tdfixed": lambda: _sapo(algo="sapo-tdfixed", actor_return="td_lambda"),
    "sapo-tdadpt": lambda: _sapo(algo="sapo-tdadpt", actor_return="td_lambda", adaptive_lambda=True),
}


def preset(name: str) -> AlgoConfig:
    if name not in PRESETS:
        raise KeyError(f"unknown algorithm {name!r}; choose from: {', '.join(PRESETS)}")
    return PRESETS[name]()
