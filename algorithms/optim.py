"""Adam and AdamW, the optimisers of the actor, the critic, phi (lambda = sigmoid(phi)) and log alpha.

The update is Adam's (Kingma & Ba 2015, Algorithm 1), with the weight decay either added to the gradient
(Adam's L2 penalty) or applied to the parameter before the step (AdamW, Loshchilov & Hutter 2019):

    m <- beta1 m + (1 - beta1) g                  (written as lerp towards g, as torch writes it)
    v <- beta2 v + (1 - beta2) g^2
    theta <- theta - lr / (1 - beta1^t) * m / (sqrt(v) / sqrt(1 - beta2^t) + eps)

It is written here rather than taken from ``torch.optim`` because building any ``torch.optim`` optimiser
imports ``torch._dynamo`` (torch's compiler front end, which this package never uses), and that import
costs every benchmark job (one process each) seconds before its first epoch. The arithmetic is torch's
single-tensor Adam operation for operation, in the same order and precision, so a run takes the same
steps bit for bit as it would with ``torch.optim.Adam`` / ``AdamW`` on the CPU; the state dict has
torch's layout, so a checkpoint written with either loads into the other. tests/test_optim.py holds
both against torch.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable

import torch
from torch import Tensor


class Adam:
    """Adam over one group of parameters; ``decoupled=True`` gives AdamW.

    What the training loop uses of torch's optimiser interface: ``param_groups[0]["lr"]`` (the learning
    rate schedule writes it), ``zero_grad``, ``step``, ``state_dict`` and ``load_state_dict``."""

    def __init__(
        self,
        params: Iterable[Tensor],
        lr: float,
        betas: tuple[float, float],
        weight_decay: float,
        decoupled: bool,
        eps: float = 1e-8,
    ):
        self.params = list(params)
        if not self.params:
            raise ValueError("Adam got no parameters")
        self.param_groups = [
            {
                "lr": lr,
                "betas": tuple(betas),
                "eps": eps,
                "weight_decay": weight_decay,
                "decoupled_weight_decay": decoupled,
            }
        ]
        self.state: dict[int, dict[str, Tensor]] = {}  # by position in params; made at a parameter's first step

    def zero_grad(self) -> None:
        for p in self.params:
            p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One Adam(W) step of every parameter that holds a gradient (the others keep their moments)."""
        group = self.param_groups[0]
        lr, (beta1, beta2), eps, decay = group["lr"], group["betas"], group["eps"], group["weight_decay"]
        for i, p in enumerate(self.params):
            if p.grad is None:
                continue
            if i not in self.state:
                # torch keeps the step count in a float32 (float64 under a float64 default) tensor
                self.state[i] = {
                    "step": torch.tensor(
                        0.0, dtype=torch.float64 if torch.get_default_dtype() == torch.float64 else torch.float32
                    ),
                    "exp_avg": torch.zeros_like(p, memory_format=torch.preserve_format),
                    "exp_avg_sq": torch.zeros_like(p, memory_format=torch.preserve_format),
                }
            state = self.state[i]
            grad = p.grad
            state["step"] += 1
            if decay != 0:
                if group["decoupled_weight_decay"]:
                    p.mul_(1 - lr * decay)
                else:
                    grad = grad.add(p, alpha=decay)
            state["exp_avg"].lerp_(grad, 1 - beta1)
            state["exp_avg_sq"].mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
            t = state["step"].item()
            step_size = lr / (1 - beta1**t)
            denom = (state["exp_avg_sq"].sqrt() / (1 - beta2**t) ** 0.5).add_(eps)
            p.addcdiv_(state["exp_avg"], denom, value=-step_size)

    def state_dict(self) -> dict:
        """torch's layout: moments by parameter position, one group with every flag torch records."""
        group = dict(self.param_groups[0])
        group.update(amsgrad=False, maximize=False, foreach=None, capturable=False, differentiable=False, fused=None)
        group["params"] = list(range(len(self.params)))
        return {"state": dict(self.state), "param_groups": [group]}

    def load_state_dict(self, saved: dict) -> None:
        """Take the moments and the hyper-parameters of a state dict of this class or of torch's Adam(W)."""
        (group,) = saved["param_groups"]
        if len(group["params"]) != len(self.params):
            raise ValueError(
                f"the state dict holds {len(group['params'])} parameters, this optimiser {len(self.params)}"
            )
        if group.get("amsgrad") or group.get("maximize"):
            raise ValueError("the state dict is of an AMSGrad or maximising Adam, which this one is not")
        position = {index: i for i, index in enumerate(group["params"])}
        state = copy.deepcopy(saved["state"])
        self.state = {}
        for index, moments in state.items():
            p = self.params[position[index]]
            self.state[position[index]] = {
                key: value if key == "step" else value.to(dtype=p.dtype, device=p.device)
                for key, value in moments.items()
            }
        keep = ("lr", "betas", "eps", "weight_decay", "decoupled_weight_decay")
        self.param_groups = [{key: group[key] for key in keep}]
        self.param_groups[0]["betas"] = tuple(self.param_groups[0]["betas"])
