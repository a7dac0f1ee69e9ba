"""Do engines simulate the same task? Measured from the same initial states and actions.

``python -m harness parity --task T [--backends A B ...]`` runs, on each backend (default: the two first
installed engines, in the adapters' table order, that drive the task), and compares every other
backend with the first:

1. **Zero-action settle**: the task's default pose at its start height, zero actions for ``settle_s``
   seconds (2 s); trunk height and every joint angle at the end, and their path.
2. **Resting contact penetration**: a probe sphere (r 0.1 m, 4.19 kg) with the task's contact
   constants resting on the ground; its penetration against the penalty law's ``m g / ke``.
3. **Joint-limit deflection under load**: a probe hinge (fixed base, no gravity) with the task's
   limit constants, pushed into its stop by a known torque; deflection against ``tau / ke``.
4. **Open-loop divergence**: the same sampled initial states and the same uniform random actions on
   both engines, no resets; the RMS over envs of the trunk-position and joint-angle differences after
   each step (1 to ``steps``).
5. **Random-policy first-episode length**: uniform random actions, ``num_envs`` envs x ``seeds``
   seeds, steps until each env's first termination (capped at ``max_steps``).

Targets (on the default presets of the Ant and the Go2): settle height within 1 cm and every joint
angle within 0.02 rad; probe penetration and deflection within 10% across engines; mean first-episode
length within 20%. The result says which hold. The probes isolate the constant conversions (one
contact, one limit) from everything else the robots do.
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from pathlib import Path

import torch

from harness.envs import make_sim
from harness.formatting import markdown_table
from simcore import ControlKind, StateLayout

TARGETS = {"settle_height_m": 0.01, "settle_joint_rad": 0.02, "probe_rel": 0.10, "episode_length_rel": 0.20}
DIVERGENCE_REPORTED = (1, 2, 5, 10, 20, 50, 100)

_SPHERE = """<mujoco model="parity_sphere"><compiler angle="degree"/>
  <worldbody><body name="ball" pos="0 0 0.1"><freejoint name="root"/>
  <geom name="ball" type="sphere" size="0.1" density="1000"/></body></worldbody></mujoco>"""
_HINGE = """<mujoco model="parity_hinge"><compiler angle="degree"/>
  <worldbody><body name="arm" pos="0 0 1">
  <joint name="hinge" type="hinge" axis="0 1 0" range="-30 30" limited="true"/>
  <geom name="arm" type="capsule" fromto="0 0 0 0.4 0 0" size="0.05" density="1000"/></body></worldbody></mujoco>"""


class _Probe:
    """A one-body task for the adapters (a ``simcore.TaskSpec``): a free sphere or a fixed hinge."""

    asset_format = "mjcf"
    control_kind = ControlKind.JOINT_TORQUE
    soft_body = None

    def __init__(self, kind: str, physics, backend_options, folder: Path):
        self.name = f"parity_{kind}"
        self.physics = physics
        self.backend_options = backend_options
        self.asset_path = folder / f"{self.name}.xml"
        self.asset_path.write_text(_SPHERE if kind == "sphere" else _HINGE)
        self.layout = StateLayout(num_dofs=0, floating_base=True) if kind == "sphere" else StateLayout(1, False)
        self.action_dim = self.layout.num_dofs
        self.kind = kind

    def sample_initial_state(self, num_envs, generator):
        if self.kind == "sphere":
            q = torch.tensor([[0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 1.0]]).repeat(num_envs, 1)
            return q, torch.zeros(num_envs, 6)
        return torch.zeros(num_envs, 1), torch.zeros(num_envs, 1)

    def actions_to_control(self, actions):
        return actions


def _probe_sim(backend: str, probe: _Probe):
    return make_sim(backend, probe, 1, seed=0, horizon=1)


def probe_penetration(backend: str, task, folder: Path, seconds: float = 3.0) -> dict:
    """Resting penetration of the probe sphere with the task's contact constants."""
    physics = dataclasses.replace(task.physics, ground_plane=True)
    probe = _Probe("sphere", physics, task.backend_options, folder)
    sim = _probe_sim(backend, probe)
    with torch.no_grad():
        for _ in range(round(seconds / physics.frame_dt)):
            state = sim.step(torch.zeros(1, 0))
    mass = 1000.0 * 4.0 / 3.0 * math.pi * 0.1**3
    return {
        "penetration_m": 0.1 - float(state.root_pos[0, 2]),
        "penalty_law_m": mass * -physics.gravity / physics.contact_ke,
    }


def probe_deflection(backend: str, task, folder: Path, seconds: float = 3.0) -> dict:
    """Deflection of the probe hinge past its 30 degree stop under ``tau = 0.05 rad x joint_limit_ke``."""
    physics = dataclasses.replace(task.physics, gravity=0.0, ground_plane=False, armature=0.0)
    probe = _Probe("hinge", physics, task.backend_options, folder)
    sim = _probe_sim(backend, probe)
    torque = 0.05 * physics.joint_limit_ke
    with torch.no_grad():
        for _ in range(round(seconds / physics.frame_dt)):
            state = sim.step(torch.full((1, 1), torque))
    return {
        "deflection_rad": float(state.joint_q[0, 0]) - math.radians(30.0),
        "penalty_law_rad": torque / physics.joint_limit_ke,
        "torque_nm": torque,
    }


def settle(backend: str, task, seconds: float = 2.0) -> dict:
    """Zero actions from the default pose: trunk height and joint angles over time and at the end."""
    sim = make_sim(backend, task, 1, seed=0, horizon=1)
    q0, qd0 = task.default_state()
    heights = []
    with torch.no_grad():
        sim.state = sim.state_from_generalized(q0.unsqueeze(0), qd0.unsqueeze(0))
        for _ in range(round(seconds / task.physics.frame_dt)):
            state = sim.step(torch.zeros(1, task.action_dim))
            heights.append(float(state.root_pos[0, 2]))
    return {"height_m": heights[-1], "joint_q": state.dof_q(sim.layout)[0].tolist(), "height_path": heights}


def open_loop(backends: list[str], task, num_envs: int, steps: int, seed: int) -> dict:
    """The same initial states and uniform random actions on every backend, no resets."""
    gen = torch.Generator().manual_seed(seed)
    actions = 2.0 * torch.rand(steps, num_envs, task.action_dim, generator=gen) - 1.0
    paths = {}
    for backend in backends:
        sim = make_sim(backend, task, num_envs, seed=seed, horizon=1)  # same seed: same initial states
        rows = []
        with torch.no_grad():
            for t in range(steps):
                try:
                    state = sim.step(actions[t])
                except FloatingPointError:
                    break
                rows.append(torch.cat((state.root_pos, state.dof_q(sim.layout)), dim=1))
        paths[backend] = torch.stack(rows) if rows else torch.zeros(0, num_envs, 3 + task.layout.num_dofs)
    reference = paths[backends[0]]
    against = {}
    for other in backends[1:]:
        n = min(reference.shape[0], paths[other].shape[0])
        diff = reference[:n] - paths[other][:n]
        pos = diff[..., :3].norm(dim=-1).pow(2).mean(dim=1).sqrt().tolist()
        joints = diff[..., 3:].pow(2).mean(dim=(1, 2)).sqrt().tolist()
        against[other] = {"steps_compared": n, "root_pos_rms_m": pos, "joint_rms_rad": joints}
    return against


def first_episode_lengths(backend: str, task, num_envs: int, seeds: int, max_steps: int) -> list[int]:
    """Steps until each env's first termination under uniform random actions (``max_steps`` if none)."""
    from tasks.env import TaskEnv

    lengths = []
    for seed in range(seeds):
        env = TaskEnv(task, make_sim(backend, task, num_envs, seed=seed, horizon=1))
        gen = torch.Generator().manual_seed(1000 + seed)
        done_at = torch.full((num_envs,), max_steps)
        alive = torch.ones(num_envs, dtype=torch.bool)
        with torch.no_grad():
            env.reset()
            for t in range(max_steps):
                terminated = env.step(2.0 * torch.rand(num_envs, task.action_dim, generator=gen) - 1.0).terminated
                ended = alive & terminated
                done_at[ended] = t + 1
                alive &= ~terminated
                if not alive.any():
                    break
        lengths += done_at.tolist()
    return lengths


def parity(
    task_name: str,
    backends: list[str],
    preset: str | None = None,
    num_envs: int = 64,
    seeds: int = 5,
    steps: int = 100,
    max_steps: int = 300,
    seed: int = 0,
    progress=print,
) -> dict:
    """Every measurement of the module docstring on ``backends``, each other backend compared with the
    first: ``comparisons`` per other backend; ``gaps`` the largest over them, ``holds`` where every one holds."""
    from tasks import make_task

    task = make_task(task_name, preset=preset)
    if task.layout.num_particles or not task.layout.floating_base:
        raise ValueError(f"parity compares floating-base robots; task {task_name!r} is not one")
    result: dict = {"task": task_name, "backends": backends, "targets": TARGETS, **task.physics_record()}
    per: dict = {b: {} for b in backends}
    with tempfile.TemporaryDirectory() as folder:
        for backend in backends:
            progress(f"parity {task_name}: {backend}: probes (contact, limit)")
            per[backend]["probe_contact"] = probe_penetration(backend, task, Path(folder))
            per[backend]["probe_limit"] = probe_deflection(backend, task, Path(folder))
            progress(f"parity {task_name}: {backend}: zero-action settle")
            per[backend]["settle"] = settle(backend, task)
            progress(f"parity {task_name}: {backend}: first episodes ({seeds} seeds x {num_envs} envs)")
            lengths = first_episode_lengths(backend, task, num_envs, seeds, max_steps)
            per[backend]["first_episode"] = {"mean": sum(lengths) / len(lengths), "lengths": lengths}
    progress(f"parity {task_name}: open-loop divergence ({steps} steps, {min(num_envs, 16)} envs)")
    loops = open_loop(backends, task, min(num_envs, 16), steps, seed)
    result["per_backend"] = per
    result["comparisons"] = {
        other: {**_compare(per[backends[0]], per[other]), "open_loop": loops[other]} for other in backends[1:]
    }
    first = result["comparisons"][backends[1]]
    result["open_loop"] = first["open_loop"]  # the first pair's, as results of two engines always held
    result["gaps"] = {k: max(c["gaps"][k] for c in result["comparisons"].values()) for k in first["gaps"]}
    result["holds"] = {k: all(c["holds"][k] for c in result["comparisons"].values()) for k in first["holds"]}
    result["passed"] = all(result["holds"].values())
    result["settings"] = {"num_envs": num_envs, "seeds": seeds, "steps": steps, "max_steps": max_steps, "seed": seed}
    return result


def _compare(a: dict, b: dict) -> dict:
    """The gaps between two backends' measurements and which targets they hold."""
    joint_gap = max(abs(x - y) for x, y in zip(a["settle"]["joint_q"], b["settle"]["joint_q"], strict=True))

    def rel(x: float, y: float) -> float:
        return abs(x - y) / max(abs(y), 1e-12)

    gaps = {
        "settle_height_m": abs(a["settle"]["height_m"] - b["settle"]["height_m"]),
        "settle_joint_rad": joint_gap,
        "probe_penetration_rel": rel(a["probe_contact"]["penetration_m"], b["probe_contact"]["penetration_m"]),
        "probe_deflection_rel": rel(a["probe_limit"]["deflection_rad"], b["probe_limit"]["deflection_rad"]),
        "episode_length_rel": rel(a["first_episode"]["mean"], b["first_episode"]["mean"]),
    }
    holds = {
        "settle_height": gaps["settle_height_m"] <= TARGETS["settle_height_m"],
        "settle_joints": gaps["settle_joint_rad"] <= TARGETS["settle_joint_rad"],
        "probe_penetration": gaps["probe_penetration_rel"] <= TARGETS["probe_rel"],
        "probe_deflection": gaps["probe_deflection_rel"] <= TARGETS["probe_rel"],
        "episode_length": gaps["episode_length_rel"] <= TARGETS["episode_length_rel"],
    }
    return {"gaps": gaps, "holds": holds}


def table(result: dict) -> str:
    """The measurements of every backend side by side, one line each, as a Markdown table; the gap is
    the largest between the first backend and any other."""
    names = result["backends"]
    per = [result["per_backend"][name] for name in names]
    vs = " vs ".join(names)
    gap_head = "gap" if len(names) == 2 else f"largest gap to {names[0]}"
    lines = [
        f"Parity of `{result['task']}` (preset `{result['preset']}`): {vs}",
        "",
    ]
    cells: list[list[str]] = []

    def row(name, values, gap, target, holds):
        cells.append([name, *values, gap, target, "yes" if holds else "no"])

    gaps, holds, targets = result["gaps"], result["holds"], result["targets"]
    blank = [""] * len(names)
    row(
        "settle trunk height (m)",
        [f"{p['settle']['height_m']:.4f}" for p in per],
        f"{gaps['settle_height_m']:.4f}",
        f"<= {targets['settle_height_m']}",
        holds["settle_height"],
    )
    row(
        "settle max joint-angle gap (rad)",
        blank,
        f"{gaps['settle_joint_rad']:.4f}",
        f"<= {targets['settle_joint_rad']}",
        holds["settle_joints"],
    )
    row(
        "probe sphere penetration (m)",
        [f"{p['probe_contact']['penetration_m']:.5f}" for p in per],
        f"{100 * gaps['probe_penetration_rel']:.1f}%",
        f"<= {100 * targets['probe_rel']:.0f}% (law: {per[0]['probe_contact']['penalty_law_m']:.5f})",
        holds["probe_penetration"],
    )
    row(
        "probe hinge deflection (rad)",
        [f"{p['probe_limit']['deflection_rad']:.5f}" for p in per],
        f"{100 * gaps['probe_deflection_rel']:.1f}%",
        f"<= {100 * targets['probe_rel']:.0f}% (law: {per[0]['probe_limit']['penalty_law_rad']:.5f})",
        holds["probe_deflection"],
    )
    row(
        "random-policy first episode (mean steps)",
        [f"{p['first_episode']['mean']:.1f}" for p in per],
        f"{100 * gaps['episode_length_rel']:.1f}%",
        f"<= {100 * targets['episode_length_rel']:.0f}%",
        holds["episode_length"],
    )
    for other, comparison in (result.get("comparisons") or {names[1]: {"open_loop": result["open_loop"]}}).items():
        loop = comparison["open_loop"]
        for step in DIVERGENCE_REPORTED:
            if step <= loop["steps_compared"]:
                gap = f"{loop['root_pos_rms_m'][step - 1]:.4f} m / {loop['joint_rms_rad'][step - 1]:.4f} rad"
                label = "" if len(names) == 2 else f" ({other})"
                row(f"open loop, step {step}: RMS root / joint gap{label}", blank, gap, "measured", True)
    lines += markdown_table(["measurement", *names, gap_head, "target", "holds"], cells)
    s = result["settings"]
    lines += [
        "",
        f"{s['num_envs']} envs x {s['seeds']} seeds for episode lengths (cap {s['max_steps']} steps); "
        f"open loop on {min(s['num_envs'], 16)} envs, seed {s['seed']}.",
    ]
    return "\n".join(lines) + "\n"


def plot(result: dict, path: Path) -> Path:
    """Settle paths, open-loop divergence and first-episode lengths, the backends side by side."""
    from harness.figures import pyplot, save_figure

    plt, _ = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    dt = result["physics"]["frame_dt"]
    for backend, per in result["per_backend"].items():
        path_h = per["settle"]["height_path"]
        axes[0].plot([dt * (i + 1) for i in range(len(path_h))], path_h, label=backend)
        axes[2].hist(per["first_episode"]["lengths"], bins=30, alpha=0.5, label=backend)
    axes[0].set(title="zero-action settle", xlabel="time (s)", ylabel="trunk height (m)")
    for other, comparison in (result.get("comparisons") or {result["backends"][1]: result}).items():
        loop = comparison["open_loop"]
        steps = range(1, loop["steps_compared"] + 1)
        axes[1].plot(steps, loop["root_pos_rms_m"], label=f"root position (m), {other}")
        axes[1].plot(steps, loop["joint_rms_rad"], label=f"joint angles (rad), {other}")
    axes[1].set(title="open-loop gap between engines", xlabel="step", ylabel="RMS over envs", yscale="log")
    axes[2].set(title="random-policy first episode", xlabel="steps", ylabel="envs")
    for ax in axes:
        ax.legend()
    fig.suptitle(f"{result['task']} ({result['preset']}): {' vs '.join(result['backends'])}")
    return save_figure(fig, path)


# -- the verb and its line in the suite's checks table ---------------------------------------------


def verb(args) -> int:
    """``python -m harness parity``: the same task on two or more engines, measured side by side."""
    from harness.envs import engines_for
    from harness.inputs import BadInput, out_stem, preflight
    from harness.results import write_check_and_table

    if args.backends is None:  # the two first installed engines that drive the task
        preflight(task=args.task)
        args.backends = engines_for(args.task)[:2]
    if len(set(args.backends)) < 2:
        raise BadInput(f"parity compares two different backends, got {' '.join(args.backends)}")
    preflight(backends=args.backends, task=args.task, preset=args.preset, out=args.out, memory=(args.num_envs, 0))
    try:
        result = parity(
            args.task,
            args.backends,
            preset=args.preset,
            num_envs=args.num_envs,
            seeds=args.episode_seeds,
            steps=args.steps,
            max_steps=args.max_steps,
            seed=args.seed,
            progress=lambda line: print(line, flush=True),
        )
    except ValueError as exc:
        raise BadInput(str(exc)) from None
    text = table(result)
    print(text)
    print(f"targets {'all hold' if result['passed'] else 'not all hold'}: {result['holds']}")
    if args.out:
        print(f"wrote {plot(result, Path(out_stem(args.out)).with_suffix('.png'))}")
        for path in write_check_and_table(args.out, "parity", result, text):
            print(f"wrote {path}")
    return 0


def summary(result: dict, kind: str) -> str:
    from harness.formatting import fmt

    g = result.get("gaps", {})
    return (
        f"engines: settle height gap {fmt(g.get('settle_height_m'))} m, joint gap "
        f"{fmt(g.get('settle_joint_rad'))} rad, first-episode length gap {fmt(g.get('episode_length_rel'))} "
        "(relative)"
    )
