"""First-order actor-critic: SHAC, SAPO and their TD-lambda variants, one epoch at a time.

One epoch (Algorithm 1 of the ARE paper):

1. Roll the policy out for ``h`` steps in ``N`` envs, keeping the autograd graph through the
   simulator (the window starts with a graph cut).
2. Actor: minimise L_theta = -(1/(N h)) sum of returns at mini-trajectory starts, with the
   h-step bootstrapped return (eq. 9, SHAC/SAPO) or the truncated TD-lambda return (eq. 12,
   TDFixed/TDAdpt); the bootstrap value carries gradient through the state into the actor.
3. TDAdpt only: update phi, lambda = sigmoid(phi), on eq. 15 with actor and critic frozen.
4. Critic: regress V_phi(s_t) onto detached TD-lambda targets (eq. 11), m_critic iterations
   over b_critic minibatches; SHAC then moves its target critic by Polyak averaging.
5. SAPO only: rewards carry the entropy bonus -alpha * log pi(a|s); the temperature alpha is
   trained towards the target entropy.

The algorithm sees only a :class:`tasks.env.TaskEnv`; no engine is imported here.
"""

from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass, field

import torch
from torch import Tensor, nn

from algorithms.config import AlgoConfig
from algorithms.grad_variance import gradient_variance
from algorithms.networks import Critic, GaussianActor, SquashedGaussianActor
from algorithms.normalization import RunningMeanStd
from algorithms.returns import (
    actor_loss_from_returns,
    critic_targets,
    h_step_returns,
    segment_starts,
    td_lambda_returns,
)

PHI_LIMIT = 10.0  # |phi| <= 10 keeps sigmoid(phi) in [4.5e-5, 1 - 4.5e-5]; float32 rounds to 1 beyond ~17


@dataclass
class Window:
    """What one rollout leaves behind; (T, N) unless noted."""

    rewards: Tensor  # with graph (entropy bonus included for SAPO)
    actor_next_values: Tensor  # bootstrap values for the actor, with graph
    target_next_values: Tensor  # bootstrap values for critic/lambda targets, detached
    terminated: Tensor
    truncated: Tensor
    obs: Tensor  # (T, N, obs_dim) normalised observations, detached
    heads: list[Tensor]  # per step (N, 2A) policy heads with retained grads
    log_probs: Tensor  # detached
    finished_returns: list[float] = field(default_factory=list)
    finished_lengths: list[int] = field(default_factory=list)
    sim_seconds: float = 0.0


def _optimizer(kind: str, params, lr: float, betas) -> torch.optim.Optimizer:
    cls = torch.optim.AdamW if kind == "adamw" else torch.optim.Adam
    return cls(params, lr=lr, betas=tuple(betas))


def _finite(norm: Tensor, limit: float) -> bool:
    return bool(torch.isfinite(norm)) and float(norm) <= limit


class FirstOrderActorCritic(nn.Module):
    def __init__(self, config: AlgoConfig, obs_dim: int, act_dim: int):
        super().__init__()
        cfg = self.cfg = config.validate()
        self.act_dim = act_dim
        actor_cls = SquashedGaussianActor if cfg.soft else GaussianActor
        self.actor = actor_cls(obs_dim, act_dim, hidden_sizes=cfg.actor_hidden)
        self.critics = nn.ModuleList(Critic(obs_dim, hidden_sizes=cfg.critic_hidden) for _ in range(cfg.num_critics))
        self.target_critics = copy.deepcopy(self.critics) if cfg.target_critic_alpha is not None else None
        if self.target_critics is not None:
            self.target_critics.requires_grad_(False)
        self.obs_rms = RunningMeanStd((obs_dim,))
        # lambda = sigmoid(phi): phi starts at logit(lam) so that lambda = cfg.lam (0.95)
        self.phi = nn.Parameter(torch.tensor(math.log(cfg.lam / (1.0 - cfg.lam)) if cfg.lam < 1.0 else math.inf))
        self.log_alpha = nn.Parameter(torch.tensor(math.log(cfg.init_alpha)))
        self.actor_opt = _optimizer(cfg.optimizer, self.actor.parameters(), cfg.actor_lr, cfg.betas)
        self.critic_opt = _optimizer(cfg.optimizer, self.critics.parameters(), cfg.critic_lr, cfg.betas)
        self.lambda_opt = torch.optim.AdamW([self.phi], lr=cfg.lambda_lr, betas=cfg.lambda_betas)
        self.alpha_opt = torch.optim.AdamW([self.log_alpha], lr=cfg.alpha_lr, betas=cfg.betas)
        self.epoch = 0

    # -- small pieces --------------------------------------------------------------------
    @property
    def lam(self) -> Tensor:
        """Current lambda (a 0-dim tensor; learnable only in TDAdpt)."""
        return torch.sigmoid(self.phi)

    @property
    def alpha(self) -> float:
        return float(self.log_alpha.detach().exp()) if self.cfg.soft else 0.0

    def normalize(self, obs: Tensor) -> Tensor:
        return self.obs_rms.normalize(obs) if self.cfg.obs_norm else obs

    def values(self, nobs: Tensor, target: bool) -> Tensor:
        """(num_critics, ...) values of normalised observations from the (target) critics."""
        nets = self.target_critics if (target and self.target_critics is not None) else self.critics
        return torch.stack([c(nobs) for c in nets])

    @torch.no_grad()
    def act(self, obs: Tensor, deterministic: bool = True) -> Tensor:
        """Actions for evaluation (no graph)."""
        head = self.actor.head(self.normalize(obs))
        eps = torch.zeros_like(head[..., : self.act_dim])
        if not deterministic:
            eps.normal_()
        return self.actor.act(head, eps)[0]

    def set_learning_rates(self, epoch: int) -> None:
        cfg = self.cfg
        frac = min(epoch / max(cfg.max_epochs, 1), 1.0) if cfg.lr_schedule == "linear" else 0.0
        for opt, lr0 in ((self.actor_opt, cfg.actor_lr), (self.critic_opt, cfg.critic_lr)):
            for group in opt.param_groups:
                group["lr"] = lr0 + (cfg.min_lr - lr0) * frac

    # -- 1. rollout ------------------------------------------------------------------------
    def rollout(self, env, track_heads: bool = True) -> Window:
        cfg = self.cfg
        env.cut_graph()  # window boundary: nothing below reaches earlier windows
        obs = env.obs
        alpha = self.alpha
        rewards, actor_v, target_v, term, trunc, obs_buf, heads, logps = [], [], [], [], [], [], [], []
        finished_r, finished_l = [], []
        sim_seconds = 0.0
        for _ in range(cfg.horizon):
            if cfg.obs_norm:
                self.obs_rms.update(obs.detach())
            nobs = self.normalize(obs)
            head = self.actor.head(nobs)
            if track_heads and head.requires_grad:
                head.retain_grad()
            action, log_prob = self.actor.act(head, torch.randn_like(head[:, : self.act_dim]))
            start = time.perf_counter()
            step = env.step(action)
            sim_seconds += time.perf_counter() - start
            reward = step.reward
            if cfg.soft:
                reward = reward - alpha * log_prob  # entropy bonus inside the return
            values = self.values(self.normalize(step.final_obs), target=True)
            actor_v.append(values.mean(0))  # SAPO: mean of the critics; SHAC: the target critic
            target_v.append(values.min(0).values.detach())  # SAPO: min; SHAC: the same critic
            rewards.append(reward)
            term.append(step.terminated)
            trunc.append(step.truncated)
            obs_buf.append(nobs.detach())
            heads.append(head)
            logps.append(log_prob.detach())
            done = step.done
            if bool(done.any()):
                finished_r += step.episode_return[done].tolist()
                finished_l += step.episode_length[done].tolist()
            obs = step.obs
        return Window(
            rewards=torch.stack(rewards),
            actor_next_values=torch.stack(actor_v),
            target_next_values=torch.stack(target_v),
            terminated=torch.stack(term),
            truncated=torch.stack(trunc),
            obs=torch.stack(obs_buf),
            heads=heads,
            log_probs=torch.stack(logps),
            finished_returns=finished_r,
            finished_lengths=finished_l,
            sim_seconds=sim_seconds,
        )

    # -- 2. actor ----------------------------------------------------------------------------
    def actor_returns(self, w: Window, rewards: Tensor | None = None, next_values: Tensor | None = None) -> Tensor:
        """h-step (eq. 9) or TD-lambda (eq. 12, lambda treated as a constant here) returns."""
        rewards = w.rewards if rewards is None else rewards
        next_values = w.actor_next_values if next_values is None else next_values
        if self.cfg.actor_return == "h_step":
            return h_step_returns(rewards, next_values, w.terminated, w.truncated, self.cfg.gamma)
        lam = self.lam.detach()
        return td_lambda_returns(rewards, next_values, w.terminated, w.truncated, self.cfg.gamma, lam)

    def actor_loss(self, w: Window) -> Tensor:
        starts = segment_starts(w.terminated, w.truncated)
        return actor_loss_from_returns(self.actor_returns(w), starts, self.cfg.horizon)

    def group_gradients(self, w: Window) -> Tensor:
        """(K, P) actor gradients of K disjoint env groups, from one backward pass.

        After ``actor_loss.backward()`` each retained policy head holds dL/dH(t, n), the total
        derivative through the simulator. Every path from theta to the loss passes through a
        head, so grad L_k = K * sum over (t, n in group k) of dL/dH(t, n) . dH(t, n)/dtheta,
        and the second factor needs only the actor network on the stored observations.
        """
        k = self.cfg.grad_var_groups
        params = [p for p in self.actor.parameters()]
        head_grads = torch.stack([h.grad for h in w.heads])  # (T, N, 2A)
        n = head_grads.shape[1]
        size = n // k
        grads = []
        for g in range(k):
            rows = slice(g * size, (g + 1) * size)
            heads = self.actor.head(w.obs[:, rows])
            flat = torch.autograd.grad((heads * head_grads[:, rows]).sum(), params, allow_unused=True)
            grads.append(
                torch.cat(
                    [
                        (x if x is not None else torch.zeros_like(p)).reshape(-1)
                        for x, p in zip(flat, params, strict=True)
                    ]
                )
            )
        return k * torch.stack(grads)

    # -- 3. lambda ---------------------------------------------------------------------------
    def lambda_update_due(self, epoch: int) -> bool:
        m = self.cfg.lambda_iterations
        return self.cfg.adaptive_lambda and (m >= 1.0 or epoch % round(1.0 / m) == 0)

    def lambda_loss(self, w: Window, predicted: Tensor, envs: slice | Tensor) -> Tensor:
        """Eq. 15: mean (V_phi(s) - G^lambda(s))^2 with actor and critic frozen (inputs detached)."""
        targets = td_lambda_returns(
            w.rewards.detach()[:, envs],
            w.target_next_values[:, envs],
            w.terminated[:, envs],
            w.truncated[:, envs],
            self.cfg.gamma,
            self.lam,
        )
        return (predicted[:, envs] - targets).pow(2).mean()

    def update_lambda(self, w: Window) -> float:
        cfg = self.cfg
        with torch.no_grad():
            predicted = self.values(w.obs, target=False).mean(0)
        n = predicted.shape[1]
        batches = torch.randperm(n).chunk(cfg.lambda_batches)
        losses = []
        for _ in range(max(1, int(cfg.lambda_iterations))):
            for envs in batches:
                loss = self.lambda_loss(w, predicted, envs)
                self.lambda_opt.zero_grad()
                loss.backward()
                if torch.isfinite(self.phi.grad):
                    self.lambda_opt.step()
                    with torch.no_grad():  # keep lambda strictly inside (0, 1) even in float32
                        self.phi.clamp_(-PHI_LIMIT, PHI_LIMIT)
                losses.append(float(loss.detach()))
        return sum(losses) / len(losses)

    # -- 4. critic ---------------------------------------------------------------------------
    def update_critic(self, w: Window) -> tuple[float, int]:
        cfg = self.cfg
        targets = critic_targets(
            w.rewards.detach(), w.target_next_values, w.terminated, w.truncated, cfg.gamma, self.lam.detach()
        ).reshape(-1)
        obs = w.obs.reshape(-1, w.obs.shape[-1])
        last, skipped = float("nan"), 0
        for _ in range(cfg.critic_iterations):
            for idx in torch.randperm(obs.shape[0]).chunk(cfg.critic_minibatches):
                predicted = self.values(obs[idx], target=False)  # (num_critics, B)
                loss = (predicted - targets[idx]).pow(2).mean(dim=1).sum()
                self.critic_opt.zero_grad()
                loss.backward()
                norm = nn.utils.clip_grad_norm_(self.critics.parameters(), cfg.critic_grad_clip)
                if _finite(norm, cfg.max_grad_norm_skip):
                    self.critic_opt.step()
                else:
                    skipped += 1
                last = float(loss.detach()) / cfg.num_critics
        if self.target_critics is not None:
            a = cfg.target_critic_alpha
            with torch.no_grad():
                for target, online in zip(self.target_critics.parameters(), self.critics.parameters(), strict=True):
                    target.mul_(a).add_((1.0 - a) * online)
        return last, skipped

    # -- 5. temperature ------------------------------------------------------------------------
    def update_alpha(self, w: Window) -> float:
        target_entropy = self.cfg.target_entropy_per_dim * self.act_dim
        entropy = -w.log_probs.mean()
        loss = self.log_alpha * (entropy - target_entropy)  # raise alpha when entropy is too low
        self.alpha_opt.zero_grad()
        loss.backward()
        self.alpha_opt.step()
        return float(entropy)

    # -- one epoch ---------------------------------------------------------------------------
    def train_epoch(self, env) -> dict:
        cfg = self.cfg
        self.set_learning_rates(self.epoch)
        w = self.rollout(env)
        metrics: dict = {"sim_forward_s": w.sim_seconds}

        start = time.perf_counter()
        loss = self.actor_loss(w)
        self.actor_opt.zero_grad()
        loss.backward()
        metrics["backward_s"] = time.perf_counter() - start

        start = time.perf_counter()
        norm = nn.utils.clip_grad_norm_(self.actor.parameters(), cfg.actor_grad_clip)
        actor_ok = bool(torch.isfinite(loss)) and _finite(norm, cfg.max_grad_norm_skip)
        grad_var = float("nan")
        if actor_ok:
            self.actor_opt.step()
            grad_var = float(gradient_variance(self.group_gradients(w)))
        lambda_loss = self.update_lambda(w) if self.lambda_update_due(self.epoch) else float("nan")
        critic_loss, critic_skipped = self.update_critic(w)
        entropy = self.update_alpha(w) if cfg.soft else float(-w.log_probs.mean())
        metrics["update_s"] = time.perf_counter() - start
        self.epoch += 1
        metrics.update(
            actor_loss=float(loss.detach()),
            actor_grad_norm=float(norm),
            actor_grad_var=grad_var,
            actor_update_skipped=not actor_ok,
            critic_loss=critic_loss,
            critic_updates_skipped=critic_skipped,
            lambda_loss=lambda_loss,
            lam=float(self.lam.detach()),
            alpha=self.alpha,
            entropy=entropy,
            finished_episodes=len(w.finished_returns),
            train_episode_return=(sum(w.finished_returns) / len(w.finished_returns)) if w.finished_returns else None,
            train_episode_length=(sum(w.finished_lengths) / len(w.finished_lengths)) if w.finished_lengths else None,
        )
        return metrics

    def parameters_finite(self) -> bool:
        return all(bool(torch.isfinite(p).all()) for p in self.state_dict().values() if p.is_floating_point())
