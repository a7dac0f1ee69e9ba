"""Env-steps per second of the peer simulator Rewarped 1.3.3 on Warp's CPU device, forward and forward+backward.

Runs only in its own virtual environment (see README.md beside this file): Rewarped pins warp-lang 1.3.3 and
usd-core 24.5, which cannot share an environment with this project's Warp 1.19.

    python benchmarks/peers/rewarped_throughput.py --env ant|soft_jumper --num-envs N --horizon H \
        --windows W --out FILE.json

What is timed, per window of H env steps (``env.step`` = Rewarped's whole step: actions -> control, the Warp
substeps, observations, reward, automatic resets):

* forward: uniform random actions in [-1, 1) under ``torch.no_grad()`` on the same gradient-enabled env
  (``no_grad=False``) that the forward+backward windows use. Rewarped still records a Warp tape and allocates
  fresh states every step on this path; ``--nograd-env`` also times a second env built in Rewarped's own
  no-grad mode (``no_grad=True``: ping-pong states, no tape), reported as ``forward_nograd_env_steps_per_s``.
* forward+backward: random actions that require grad, a scalar loss that sums every env's differentiable state
  (``env.state_tensors``: joint_q and joint_qd for the Ant, particle_q and particle_qd for the SoftJumper) after
  every step, then ``loss.backward()`` through Rewarped's ``UpdateFunction`` (Warp tape backward).

Before each window the graph is cut the way Mineral's BPTT/SHAC do it: ``env.initialize_trajectory()``
(``clear_grad()``: detached clones of the state, control and buffers written back into the Warp arrays). After
each window the envs are reset outside the timer (``env.reset(clear_grad=True)``), as this project's harness
does, so every window starts from the initial-state distribution; ``--no-reset-between-windows`` instead keeps
rolling on, as Mineral does. One warm-up window of each kind first (Warp compiles kernels on first use), then the
kinds are interleaved window by window and the best of W is reported: env-steps/s = N * H / best seconds.
"""

from __future__ import annotations

import argparse
import datetime
import importlib
import json
import os
import platform
import shlex
import sys
import time
from importlib import metadata

DEFAULT_WARP_CACHE = "/tmp/warpcache_rewarped"

#: --env name -> (Rewarped module, class, extra constructor kwargs)
ENVS = {
    "ant": ("rewarped.envs.dflex.ant", "Ant", {}),
    "soft_jumper": ("rewarped.envs.gradsim.jumper", "Jumper", {"which": "table"}),
}

GRAPH_CUT = (
    "before every window env.initialize_trajectory() = WarpEnv.clear_grad() + compute_observations(): the state "
    "tensors (and control, actions, reward/reset/progress buffers) are replaced by detached clones that are also "
    "written back into the Warp state arrays, as Mineral's BPTT/SHAC do at the start of each horizon"
)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env", required=True, choices=sorted(ENVS))
    p.add_argument("--num-envs", type=int, required=True)
    p.add_argument("--horizon", type=int, required=True, help="env steps per window")
    p.add_argument("--windows", type=int, default=5, help="timed windows of each kind (best of W is reported)")
    p.add_argument("--out", required=True, help="JSON file to write")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--episode-length", type=int, default=None, help="override Rewarped's episode length (Ant 1000, Jumper 300)"
    )
    p.add_argument(
        "--early-termination",
        choices=("default", "on", "off"),
        default="default",
        help="Ant: fall below 0.27 m ends the episode (Rewarped default on); the Jumper supports only off",
    )
    p.add_argument(
        "--no-reset-between-windows",
        action="store_true",
        help="keep rolling on across windows (Mineral style) instead of resetting all envs after each window",
    )
    p.add_argument(
        "--nograd-env",
        action="store_true",
        help="also time forward windows on a second env built with Rewarped's no_grad=True mode",
    )
    args = p.parse_args(argv)
    for name in ("num_envs", "horizon", "windows"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1")
    if args.env == "soft_jumper" and args.early_termination == "on":
        p.error("Rewarped's Jumper raises NotImplementedError for early termination")
    return args


def cpu_model() -> str | None:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def package_versions() -> dict[str, str | None]:
    out = {}
    for name in ("rewarped", "warp-lang", "torch", "numpy", "usd-core", "gym", "trimesh", "pycollada"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def build_env(args: argparse.Namespace, no_grad: bool):
    module_name, class_name, extra = ENVS[args.env]
    cls = getattr(importlib.import_module(module_name), class_name)
    # The keyword set Mineral's Rewarped task passes (cfgs/task/Rewarped.yaml + envs/rewarped.py make_envs).
    kwargs = dict(
        num_envs=args.num_envs,
        device="cpu",
        seed=args.seed,
        randomize=True,
        no_grad=no_grad,
        render=False,
        no_env_offset=True,
        **extra,
    )
    if args.episode_length is not None:
        kwargs["episode_length"] = args.episode_length
    if args.early_termination != "default":
        kwargs["early_termination"] = args.early_termination == "on"
    env = cls(**kwargs)
    env.reset()  # first reset builds the model, integrator and buffers (WarpEnv.init)
    return env, f"{module_name}.{class_name}", kwargs


def state_sum(tensors):
    """Sum of every env's differentiable state (Rewarped's UpdateFunction outputs: env.state_tensors)."""
    total = None
    for t in tensors:
        total = t.sum() if total is None else total + t.sum()
    return total


def forward_window(env, horizon: int, gen) -> tuple[float, int]:
    import torch

    env.initialize_trajectory()
    actions = 2.0 * torch.rand((horizon, env.num_envs, env.num_actions), generator=gen) - 1.0
    dones = []
    with torch.no_grad():
        start = time.perf_counter()
        for t in range(horizon):
            _, _, done, _ = env.step(actions[t])
            dones.append(done.clone())
        elapsed = time.perf_counter() - start
    return elapsed, int(sum(int(d.sum()) for d in dones))


def forward_backward_window(env, horizon: int, gen) -> tuple[float, int, dict]:
    import torch

    env.initialize_trajectory()
    actions = (2.0 * torch.rand((horizon, env.num_envs, env.num_actions), generator=gen) - 1.0).requires_grad_(True)
    # WarpEnv.step() resets finished envs before it returns, replacing the state tensors with fresh leaves; keep
    # the pre-reset (graph-connected) state of that step for the loss, as Rewarped keeps obs_before_reset.
    pre_reset = []
    step_reset = env.reset

    def capturing_reset(env_ids=None, clear_grad=False):
        pre_reset.append(list(env.state_tensors))
        return step_reset(env_ids, clear_grad)

    dones = []
    env.reset = capturing_reset  # instance attribute: only the resets called from inside env.step()
    try:
        start = time.perf_counter()
        loss = torch.zeros(())
        for t in range(horizon):
            _, _, done, _ = env.step(actions[t])
            dones.append(done.clone())
            loss = loss + state_sum(pre_reset.pop() if pre_reset else env.state_tensors)
        loss.backward()
        elapsed = time.perf_counter() - start
    finally:
        del env.reset
    g = actions.grad
    per_step = [float(x) for x in g.reshape(horizon, -1).norm(dim=1)] if g is not None else []
    check = {
        "loss": float(loss.detach()),
        "action_grad_norm": float(g.norm()) if g is not None else None,
        "action_grad_finite": bool(torch.isfinite(g).all()) if g is not None else False,
        "action_grad_nonzero_fraction": float((g != 0).float().mean()) if g is not None else 0.0,
        "action_grad_norm_per_step": per_step,
    }
    return elapsed, int(sum(int(d.sum()) for d in dones)), check


def sim_info(env) -> dict:
    model = env.model
    n = env.num_envs
    info = {
        "integrator_type": env.integrator_type.value,
        "integrator_class": f"{type(env.integrator).__module__}.{type(env.integrator).__name__}",
        "sim_substeps": env.sim_substeps,
        "sim_dt": env.sim_dt,
        "frame_dt": env.frame_dt,
        "episode_length": env.episode_length,
        "early_termination": env.early_termination,
        "num_obs": env.num_obs,
        "num_actions": env.num_actions,
        "action_scale": getattr(env, "action_scale", None),
        "state_tensors_names": list(env.state_tensors_names or ()),
        "control_tensors_names": list(env.control_tensors_names or ()),
    }
    if env.integrator_type.value == "featherstone":
        info["integrator_settings"] = dict(env.featherstone_settings)
    elif env.integrator_type.value == "euler":
        info["integrator_settings"] = dict(env.euler_settings)
    counts = {}
    for name in (
        "particle_count",
        "tet_count",
        "tri_count",
        "edge_count",
        "spring_count",
        "body_count",
        "joint_count",
        "joint_dof_count",
        "joint_coord_count",
        "shape_count",
        "articulation_count",
    ):
        value = getattr(model, name, None)
        if isinstance(value, int):
            counts[name] = value
            # per env where it divides evenly (the ground plane is one extra shape of the whole model)
            counts[name.replace("_count", "_per_env")] = None if value % n else value // n
    info["model_counts"] = counts
    for name in ("which", "act_downsample", "act_padding", "particle_q_downsample"):
        if hasattr(env, name):
            info[name] = getattr(env, name)
    return info


def time_windows(env, args: argparse.Namespace, gen, after_window) -> tuple[dict, dict, list, dict, dict]:
    """One warm-up window of each kind (Warp compiles kernels on first launch), then W windows of each kind,
    interleaved: (seconds per kind, resets per kind, the timed windows' gradient checks, warm-up seconds,
    the warm-up's gradient check)."""
    warm = {}
    warm["forward"], _ = forward_window(env, args.horizon, gen)
    after_window(env, True)
    warm["forward_backward"], _, warm_check = forward_backward_window(env, args.horizon, gen)
    after_window(env, True)
    print(f"warm-up: forward {warm['forward']:.3f} s, forward+backward {warm['forward_backward']:.3f} s")
    print(
        f"warm-up action-gradient norm {warm_check['action_grad_norm']:.6g} (finite {warm_check['action_grad_finite']})"
    )

    times = {"forward": [], "forward_backward": []}
    resets = {"forward": 0, "forward_backward": 0}
    checks = []
    for w in range(args.windows):
        sec, r = forward_window(env, args.horizon, gen)
        after_window(env, True)
        times["forward"].append(sec)
        resets["forward"] += r
        sec, r, check = forward_backward_window(env, args.horizon, gen)
        after_window(env, True)
        times["forward_backward"].append(sec)
        resets["forward_backward"] += r
        checks.append(check)
        print(
            f"window {w}: forward {times['forward'][-1]:.4f} s, forward+backward {sec:.4f} s, "
            f"action-gradient norm {check['action_grad_norm']:.6g} (finite {check['action_grad_finite']}, "
            f"non-zero fraction {check['action_grad_nonzero_fraction']:.3f}), resets in window {r}"
        )
    return times, resets, checks, warm, warm_check


def time_nograd_env(args: argparse.Namespace, gen, after_window) -> dict:
    """``--nograd-env``: forward windows on a second env built in Rewarped's no_grad=True mode."""
    import warp as wp

    enable_backward = wp.config.enable_backward
    t1 = time.perf_counter()
    env_ng, _, _ = build_env(args, no_grad=True)
    nograd_build_s = time.perf_counter() - t1
    wp.config.enable_backward = enable_backward  # WarpEnv.__init__ sets it globally from no_grad
    warm_ng, _ = forward_window(env_ng, args.horizon, gen)
    after_window(env_ng, False)
    ng_times, ng_resets = [], 0
    for _ in range(args.windows):
        sec, r = forward_window(env_ng, args.horizon, gen)
        after_window(env_ng, False)
        ng_times.append(sec)
        ng_resets += r
    return {
        "steps_per_s": args.num_envs * args.horizon / min(ng_times),
        "window_seconds": ng_times,
        "warmup_seconds": warm_ng,
        "env_build_seconds": nograd_build_s,
        "resets": ng_resets,
    }


def reset_handling(reset_between: bool) -> str:
    """How Rewarped's automatic resets are treated in the timed windows (recorded in the result)."""
    return (
        "Rewarped auto-resets inside env.step (truncation at episode_length; Ant early termination below "
        "0.27 m). Resets are kept, timed and counted. A reset builds a fresh Warp state whose tensors are "
        "new leaves (values of non-reset envs are copied in without a graph), so it cuts the gradient path "
        "of all envs (not only the reset ones) between the steps before and after it. The backward pass "
        "still runs over every step taken; the loss term of a reset step uses the pre-reset state of that "
        "step (captured by wrapping env.reset during the window), so no step's loss is lost. "
        + (
            "All envs are reset after every window, outside the timer."
            if reset_between
            else "No reset between windows (rolling on)."
        )
    )


def machine() -> dict:
    """The machine, interpreter and threads the timings were taken on."""
    import torch
    import warp as wp

    return {
        "packages": package_versions(),
        "command": shlex.join([sys.executable, *sys.argv]),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpu_affinity": len(os.sched_getaffinity(0)),
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "torch_num_threads": torch.get_num_threads(),
        "warp_device": str(wp.get_device("cpu")),
        "warp_kernel_cache": wp.config.kernel_cache_dir,
    }


def print_summary(args: argparse.Namespace, class_path: str, info: dict, fwd: float, fwd_bwd: float, nograd) -> None:
    print(f"{args.env} ({class_path}), {args.num_envs} envs x {args.horizon} steps, best of {args.windows}:")
    print(f"  forward (torch.no_grad, grad-enabled env): {fwd:.1f} env-steps/s")
    print(f"  forward+backward:                          {fwd_bwd:.1f} env-steps/s")
    if nograd is not None:
        print(f"  forward (Rewarped no_grad=True env):       {nograd['steps_per_s']:.1f} env-steps/s")
    print(
        f"  sim: {info['integrator_type']} integrator, {info['sim_substeps']} substeps, sim_dt {info['sim_dt']:.6g} s"
    )


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    os.environ.setdefault("WARP_CACHE_PATH", DEFAULT_WARP_CACHE)
    if os.environ.get("OMP_NUM_THREADS") is None:
        print("warning: OMP_NUM_THREADS is not set; the project's measurements use OMP_NUM_THREADS=1", file=sys.stderr)

    import torch

    try:
        import rewarped  # noqa: F401  (patches warp.sim and calls wp.init())
    except ImportError as e:
        sys.exit(f"rewarped is not importable ({e}); run this with the venv from benchmarks/peers/README.md")

    torch.manual_seed(args.seed)  # Rewarped's randomize_init draws from torch's global generator
    gen = torch.Generator().manual_seed(args.seed + 1)  # actions
    loadavg_start = os.getloadavg()

    t0 = time.perf_counter()
    env, class_path, env_kwargs = build_env(args, no_grad=False)
    build_s = time.perf_counter() - t0
    assert env.requires_grad and env.model.requires_grad
    info = sim_info(env)
    reset_between = not args.no_reset_between_windows

    def after_window(e, grad: bool) -> None:
        if reset_between:
            e.reset(clear_grad=grad)

    times, resets, checks, warm, warm_check = time_windows(env, args, gen, after_window)
    nograd = time_nograd_env(args, gen, after_window) if args.nograd_env else None
    steps = args.num_envs * args.horizon
    fwd = steps / min(times["forward"])
    fwd_bwd = steps / min(times["forward_backward"])
    print_summary(args, class_path, info, fwd, fwd_bwd, nograd)

    grads_ok = all(
        c["action_grad_finite"] and c["action_grad_norm"] is not None and c["action_grad_norm"] > 0
        for c in (warm_check, *checks)
    )
    result = {
        "env": args.env,
        "rewarped_class": class_path,
        "rewarped_env_kwargs": env_kwargs,
        "num_envs": args.num_envs,
        "horizon": args.horizon,
        "windows": args.windows,
        "forward_steps_per_s": fwd,
        "forward_backward_steps_per_s": fwd_bwd,
        "forward_nograd_env_steps_per_s": nograd["steps_per_s"] if nograd else None,
        "gradient_cost_factor": fwd / fwd_bwd,
        "forward_mode": "env.step under torch.no_grad() on the no_grad=False env (Warp tape still recorded)",
        "forward_backward_mode": "sum of env.state_tensors after every step, loss.backward() once per window",
        "sim_substeps": info["sim_substeps"],
        "sim_dt": info["sim_dt"],
        "frame_dt": info["frame_dt"],
        "integrator": info["integrator_type"],
        "particle_count_per_env": info["model_counts"].get("particle_per_env"),
        "tet_count_per_env": info["model_counts"].get("tet_per_env"),
        "sim": info,
        "window_seconds": times,
        "warmup_seconds": warm,
        "env_build_seconds": build_s,
        "nograd_env": nograd,
        "reset_between_windows": reset_between,
        "resets_in_timed_windows": resets,
        "graph_cut": GRAPH_CUT,
        "reset_handling": reset_handling(reset_between),
        "gradient_check": {"all_windows_finite_and_nonzero": grads_ok, "warmup": warm_check, "timed": checks},
        **machine(),
        "loadavg_start": loadavg_start,
        "loadavg_end": os.getloadavg(),
        "created_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
    }
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(result, f, indent=1, default=_jsonable)
        f.write("\n")
    print(f"wrote {args.out}")
    if not grads_ok:
        print("error: an action gradient was zero or not finite", file=sys.stderr)
        return 1
    return 0


def _jsonable(x):
    if hasattr(x, "tolist"):
        return x.tolist()
    return str(x)


if __name__ == "__main__":
    sys.exit(main())
