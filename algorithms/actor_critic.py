"""First-order actor-critic: SHAC, SAPO and their TD-lambda variants, one epoch at a time.

One epoch (Algorithm 1 of the ARE paper):

1. Roll the policy out for ``h`` steps in ``N`` envs, keeping the autograd graph through the
   simulator (the window starts with a graph cut).
2. Actor: minimise L_theta = -(1/(N h)) sum of returns at mini-trajectory starts, with the
   h-step bootstrapped return (eq. 9, SHAC/SAPO) or the truncated TD-lambda return (eq. 12,
   TDFixed/TDAdpt); the bootstrap value carries gradient through the state into the actor.
3. SAPO only: the temperature alpha is trained towards the target entropy (Mineral's order:
   right after the actor, so the critic targets below use the new alpha).
4. TDAdpt only: update phi, lambda = sigmoid(phi), on eq. 15 with actor and critic frozen.
5. Critic: regress V_phi(s_t) onto detached TD-lambda targets (eq. 11), m_critic iterations
   over b_critic minibatches; SHAC then moves its target critic by Polyak averaging.

SAPO's entropy bonus (Mineral's ``DFlexAntSAPO``): at every step the reward gains
``alpha * (H + |T|) / (2 |T|)``, where ``H`` is a one-sample estimate of the policy's entropy at
s_t (``-log pi`` of a second, independent sample, differentiable) and ``T = -0.5 |A|`` the target
entropy; the actor's return uses the alpha of the rollout, the critic (and lambda) targets the
alpha after this epoch's temperature update, on the detached entropies of the rollout.

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
from algorithms.grad_variance import gradient_statistics
from algorithms.networks import STYLES, Critic, GaussianActor, SquashedGaussianActor
from algorithms.normalization import RunningMeanStd
from algorithms.optim import Adam
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
    env_rewards: Tensor  # the task's rewards, detached (no entropy bonus)
    entropies: Tensor  # SAPO: one-sample entropy estimates H(pi(.|s_t)), detached; zeros otherwise
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


def _optimizer(kind: str, params, lr: float, betas, weight_decay: float) -> Adam:
    return Adam(params, lr=lr, betas=betas, weight_decay=weight_decay, decoupled=kind == "adamw")


def _finite(norm: Tensor, limit: float) -> bool:
    return bool(torch.isfinite(norm)) and float(norm) <= limit


class FirstOrderActorCritic(nn.Module):
    def __init__(self, config: AlgoConfig, obs_dim: int, act_dim: int):
        super().__init__()
        cfg = self.cfg = config
        self.act_dim = act_dim
        actor_cls = SquashedGaussianActor if cfg.soft else GaussianActor
        actor_style, critic_style = STYLES[cfg.network_style]
        self.actor = actor_cls(obs_dim, act_dim, cfg.actor_hidden, **actor_style)
        self.critics = nn.ModuleList(Critic(obs_dim, cfg.critic_hidden, **critic_style) for _ in range(cfg.num_critics))
        self.target_critics = copy.deepcopy(self.critics) if cfg.target_critic_alpha is not None else None
        if self.target_critics is not None:
            self.target_critics.requires_grad_(False)
        self.obs_rms = RunningMeanStd((obs_dim,))
        # TDAdpt: lambda = sigmoid(phi), phi starts at logit(lam) so that lambda = cfg.lam (0.95). Without
        # adaptation lambda is the constant cfg.lam (1.0 allowed) and phi stays a finite, unused 0.
        phi0 = math.log(cfg.lam / (1.0 - cfg.lam)) if cfg.adaptive_lambda else 0.0
        self.phi = nn.Parameter(torch.tensor(phi0))
        self.log_alpha = nn.Parameter(torch.tensor(math.log(cfg.init_alpha)))
        self.actor_opt = _optimizer(cfg.optimizer, self.actor.parameters(), cfg.actor_lr, cfg.betas, cfg.weight_decay)
        self.critic_opt = _optimizer(
            cfg.optimizer, self.critics.parameters(), cfg.critic_lr, cfg.betas, cfg.weight_decay
        )
        # weight decay set explicitly (torch's AdamW default is 0.01): see AlgoConfig.lambda_weight_decay
        self.lambda_opt = _optimizer("adamw", [self.phi], cfg.lambda_lr, cfg.lambda_betas, cfg.lambda_weight_decay)
        self.alpha_opt = _optimizer("adamw", [self.log_alpha], cfg.alpha_lr, cfg.betas, cfg.alpha_weight_decay)
        self.epoch = 0

    # -- small pieces --------------------------------------------------------------------
    @property
    def lam(self) -> Tensor:
        """Current lambda (a 0-dim tensor): sigmoid(phi) in TDAdpt, the constant cfg.lam otherwise."""
        if self.cfg.adaptive_lambda:
            return torch.sigmoid(self.phi)
        return self.phi.new_tensor(self.cfg.lam)

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
    def rollout(self, env, track_heads: bool = True, feedback: bool = True, bootstrap: bool = True) -> Window:
        """``feedback=False`` detaches the observations the policy reads (its actions still drive the
        simulator: the gradient keeps the open-loop path action -> later states -> rewards but loses
        state -> policy -> action); ``bootstrap=False`` detaches the states the critic reads for the
        actor's bootstrap values. Both on in training; ``harness grad-paths`` switches them."""
        cfg = self.cfg
        env.cut_graph()  # window boundary: nothing below reaches earlier windows
        obs = env.obs
        alpha = self.alpha  # the rollout's temperature, a constant inside the actor's return
        # DiffRL and Mineral normalise a rollout with the statistics frozen at its start
        frozen_rms = copy.deepcopy(self.obs_rms)
        names = ("rewards", "env_rewards", "entropies", "actor_v", "target_v", "term", "trunc", "obs", "logp")
        columns: dict[str, list[Tensor]] = {k: [] for k in names}
        heads, finished_r, finished_l = [], [], []
        sim_seconds = 0.0
        for _ in range(cfg.horizon):
            nobs = frozen_rms.normalize(obs) if cfg.obs_norm else obs
            if cfg.obs_norm:
                self.obs_rms.update(obs.detach())
            head = self.actor.head(nobs if feedback else nobs.detach())
            if track_heads and head.requires_grad:
                head.retain_grad()
            action, log_prob = self.actor.act(head, torch.randn_like(head[:, : self.act_dim]))
            start = time.perf_counter()
            step = env.step(action)
            sim_seconds += time.perf_counter() - start
            reward, entropy = step.reward, torch.zeros_like(step.reward)
            if cfg.soft:  # Mineral's entropy estimate: -log pi of a second, independent sample
                entropy = -self.actor.act(head, torch.randn_like(head[:, : self.act_dim]))[1]
                reward = reward + alpha * self.scaled_entropy(entropy)
            final_nobs = frozen_rms.normalize(step.final_obs) if cfg.obs_norm else step.final_obs
            values = self.values(final_nobs if bootstrap else final_nobs.detach(), target=True)
            for key, value in (
                ("rewards", reward),
                ("env_rewards", step.reward.detach()),
                ("entropies", entropy.detach()),
                ("actor_v", values.mean(0)),  # SAPO: mean of the critics; SHAC: the target critic
                ("target_v", values.min(0).values.detach()),  # SAPO: min; SHAC: the same critic
                ("term", step.terminated),
                ("trunc", step.truncated),
                ("obs", nobs.detach()),
                ("logp", log_prob.detach()),
            ):
                columns[key].append(value)
            heads.append(head)
            done = step.done
            if bool(done.any()):
                finished_r += step.episode_return[done].tolist()
                finished_l += step.episode_length[done].tolist()
            obs = step.obs
        c = {k: torch.stack(v) for k, v in columns.items()}
        return Window(
            rewards=c["rewards"],
            env_rewards=c["env_rewards"],
            entropies=c["entropies"],
            actor_next_values=c["actor_v"],
            target_next_values=c["target_v"],
            terminated=c["term"],
            truncated=c["trunc"],
            obs=c["obs"],
            heads=heads,
            log_probs=c["logp"],
            finished_returns=finished_r,
            finished_lengths=finished_l,
            sim_seconds=sim_seconds,
        )

    def scaled_entropy(self, entropy: Tensor) -> Tensor:
        """Mineral's entropy bonus per unit alpha: (H + |T|) / (2 |T|), T the target entropy."""
        scale = abs(self.cfg.target_entropy_per_dim * self.act_dim)
        return (entropy + scale) / (2.0 * scale)

    def target_rewards(self, w: Window) -> Tensor:
        """Detached rewards of the critic and lambda targets: SAPO adds the bonus at the current alpha."""
        if not self.cfg.soft:
            return w.env_rewards
        return w.env_rewards + self.alpha * self.scaled_entropy(w.entropies)

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

    def reward_weight(self, w: Window) -> float:
        """The actor loss's effective reward weight: W = -h sum_(t, n) dL/dr(t, n), the total weight its
        returns put on an env's window of rewards (the mean over envs; L averages them), in units of one
        return: one segment of the h-step return weighs sum_l gamma^l, of eq. 12's sum_l (gamma lambda)^l.
        The loss's size, and so the raw gradient variance's, scales with it; the scale-free statistics
        do not."""
        rewards = w.rewards.detach().requires_grad_(True)
        returns = self.actor_returns(w, rewards=rewards, next_values=w.actor_next_values.detach())
        starts = segment_starts(w.terminated, w.truncated)
        (grad,) = torch.autograd.grad(actor_loss_from_returns(returns, starts, self.cfg.horizon), rewards)
        return float(-grad.sum() * self.cfg.horizon)

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

    # -- 3. temperature (SAPO) -------------------------------------------------------------
    def update_alpha(self, w: Window) -> float:
        """Mineral's temperature loss: alpha * |T| * (H - T), H the rollout's mean entropy estimate."""
        target_entropy = self.cfg.target_entropy_per_dim * self.act_dim
        entropy = w.entropies.mean()
        loss = self.log_alpha.exp() * abs(target_entropy) * (entropy - target_entropy)  # alpha up when H < T
        self.alpha_opt.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_([self.log_alpha], self.cfg.alpha_grad_clip)
        self.alpha_opt.step()
        return float(entropy)

    # -- 4. lambda (TDAdpt) ------------------------------------------------------------------
    def lambda_update_due(self, epoch: int) -> bool:
        m = self.cfg.lambda_iterations
        return self.cfg.adaptive_lambda and (m >= 1.0 or epoch % round(1.0 / m) == 0)

    def lambda_loss(self, w: Window, rewards: Tensor, predicted: Tensor, envs: slice | Tensor) -> Tensor:
        """Eq. 15: mean (V_phi(s) - G^lambda(s))^2 with actor and critic frozen (inputs detached)."""
        targets = td_lambda_returns(
            rewards[:, envs],
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
        rewards = self.target_rewards(w)
        n = predicted.shape[1]
        batches = torch.randperm(n).chunk(cfg.lambda_batches)
        losses = []
        for _ in range(max(1, int(cfg.lambda_iterations))):
            for envs in batches:
                loss = self.lambda_loss(w, rewards, predicted, envs)
                self.lambda_opt.zero_grad()
                loss.backward()
                if torch.isfinite(self.phi.grad):
                    self.lambda_opt.step()
                    with torch.no_grad():  # keep lambda strictly inside (0, 1) even in float32
                        self.phi.clamp_(-PHI_LIMIT, PHI_LIMIT)
                losses.append(float(loss.detach()))
        return sum(losses) / len(losses)

    # -- 5. critic ---------------------------------------------------------------------------
    def update_critic(self, w: Window) -> tuple[float, int]:
        cfg = self.cfg
        targets = critic_targets(
            self.target_rewards(w), w.target_next_values, w.terminated, w.truncated, cfg.gamma, self.lam.detach()
        ).reshape(-1)
        obs = w.obs.reshape(-1, w.obs.shape[-1])
        last, skipped = float("nan"), 0
        for _ in range(cfg.critic_iterations):
            for idx in torch.randperm(obs.shape[0]).chunk(cfg.critic_minibatches):
                predicted = self.values(obs[idx], target=False)  # (num_critics, B)
                loss = (predicted - targets[idx]).pow(2).mean()  # averaged over the critics, as Mineral
                self.critic_opt.zero_grad()
                loss.backward()
                norm = nn.utils.clip_grad_norm_(self.critics.parameters(), cfg.critic_grad_clip)
                if _finite(norm, cfg.max_grad_norm_skip):
                    self.critic_opt.step()
                else:
                    skipped += 1
                last = float(loss.detach())
        if self.target_critics is not None:
            a = cfg.target_critic_alpha
            with torch.no_grad():
                for target, online in zip(self.target_critics.parameters(), self.critics.parameters(), strict=True):
                    target.mul_(a).add_((1.0 - a) * online)
        return last, skipped

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
        grad_stats = dict.fromkeys(("grad_var", "grad_nsr", "grad_cosine", "grad_mean_norm"), float("nan"))
        if actor_ok:
            # the group gradients are those of this update: take them before the weights move
            grad_stats = gradient_statistics(self.group_gradients(w))
            self.actor_opt.step()
        entropy = self.update_alpha(w) if cfg.soft else float(-w.log_probs.mean())
        lambda_start = time.perf_counter()
        metrics["actor_update_s"] = lambda_start - start  # clipping, gradient variance, the step, SAPO's alpha
        lambda_loss = self.update_lambda(w) if self.lambda_update_due(self.epoch) else float("nan")
        critic_start = time.perf_counter()
        metrics["lambda_update_s"] = critic_start - lambda_start
        critic_loss, critic_skipped = self.update_critic(w)
        end = time.perf_counter()
        metrics["critic_update_s"] = end - critic_start
        metrics["update_s"] = end - start
        self.epoch += 1
        metrics.update(
            actor_loss=float(loss.detach()),
            actor_grad_norm=float(norm),
            # raw variance (scales with the loss squared) and the scale-free statistics (grad_variance.py)
            actor_grad_var=grad_stats["grad_var"],
            actor_grad_nsr=grad_stats["grad_nsr"],
            actor_grad_cosine=grad_stats["grad_cosine"],
            actor_grad_mean_norm=grad_stats["grad_mean_norm"],
            actor_reward_weight=self.reward_weight(w),
            actor_update_skipped=not actor_ok,
            critic_loss=critic_loss,
            critic_updates_skipped=critic_skipped,
            lambda_loss=lambda_loss,
            lam=float(self.lam.detach()),
            alpha=self.alpha,
            entropy=entropy,
            # mean task reward per env and step of this window (no entropy bonus): a learning signal every
            # epoch, also before the first episode ends (the Ant's and Go2's last 1000 steps)
            train_reward_per_step=float(w.env_rewards.mean()),
            finished_episodes=len(w.finished_returns),
            train_episode_return=(sum(w.finished_returns) / len(w.finished_returns)) if w.finished_returns else None,
            train_episode_length=(sum(w.finished_lengths) / len(w.finished_lengths)) if w.finished_lengths else None,
        )
        return metrics

    def parameters_finite(self) -> bool:
        return all(bool(torch.isfinite(p).all()) for p in self.state_dict().values() if p.is_floating_point())
