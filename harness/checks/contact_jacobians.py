"""Per-step Jacobians checked where training runs: at states sampled in contact.

``gradcheck`` differentiates a contact-free segment, where a step is smooth and a finite difference
is an exact reference. Training runs on the ground. This check samples states from real rollouts
(after a settle, every ``stride`` steps, each env one trajectory, reset when it terminates as in
training) of two kinds: half under uniformly random actions, half under a policy, SHAC trained
briefly on Newton for the purpose and acting stochastically as in training (the states early
training visits). It keeps those MuJoCo C finds in contact and compares, at each state, the
Jacobian of the next state with respect to the state and the actions with a reference:

* **MuJoCo-Warp**: the adapter's own finite-difference Jacobians (:meth:`MujocoWarpSim.fd_jacobians`,
  what its backward pass multiplies by) against MuJoCo C in float64 on the same model and state,
  central differences with a 1e-6 step (:func:`backends.mujoco_warp.reference.float64_step_jacobians`),
  with the solver's tolerance set to 0 so that every solve runs its full iteration count and nominal
  and perturbed solves are comparable (the warm start is zeroed in both, as in the adapter).
* **Newton**: the tape's Jacobian (autograd through ``advance``, one backward pass per output
  coordinate) against central differences of the same float32 step, swept over step sizes. Where
  the step is smooth around a state, the differences of two neighbouring step sizes agree (a
  plateau) and the tape should agree with them; where they never agree, the step is not smooth at
  that scale (a contact or limit switching inside the stencil) and no finite difference is a
  reference.

A control runs beside every check: the same states lifted clear of the ground (root at the task's
``airborne_height``), where the comparison must agree; it shows that a disagreement in contact is
the contact's, not the comparison's.

Both are compared in the engine-neutral coordinates the algorithms see, except MuJoCo-Warp's, which
are the adapter's own tangent coordinates (the ones its finite differences perturb). Newton's input
columns exclude the root quaternion (a perturbation would leave the unit sphere). Per state: the
relative Frobenius error ``||J - J_ref|| / ||J_ref||`` and the cosine of the flattened matrices.

Each state is also classified by MuJoCo C on the task's model (stepped through the same control
step): whether it is in contact, whether a contact is made or broken during the step (onset),
whether a joint limit is active, and whether friction sticks or slides
(:func:`backends.mujoco_warp.reference.classify_step`). A state counts as agreeing at 5% (or 20%)
relative error.

Each state also records how strongly the step amplifies a state perturbation, the quantity a
window's gradient multiplies ``h`` times: the spectral norm of the state Jacobian (the gain), and of
its velocity-from-position block (a contact's stiffness shows there: a penetration's change becomes
a velocity change within one step) and velocity-from-velocity block, all over the position columns
both engines share (root rotation excluded). For MuJoCo-Warp the reference's gains are recorded too,
so a gain larger than Newton's is told apart as MuJoCo's physics (the reference has it) or its
differences (only the adapter has it).

A reference needs the tape to replay what its forward did: the tape's Jacobian takes one backward
pass per output coordinate through the same step, which the contract requires to give the same
gradient every time (``tests/test_contract.py``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import torch

# MuJoCo C stays behind the adapter package: the classifier and the accurate-solver model live there
from backends.contract import BackendError
from backends.mujoco_warp.reference import accurate_model, classify_step
from harness.envs import make_sim
from harness.formatting import markdown_table

#: Newton's finite-difference step sizes (float32: round-off grows as the step shrinks)
NEWTON_EPS = (1e-2, 3e-3, 1e-3, 3e-4, 1e-4)
#: two neighbouring step sizes whose differences agree this closely bound a plateau
PLATEAU = 0.05
THRESHOLDS = (0.05, 0.2)
#: the per-state gains (:func:`gains`) the summaries take medians of
GAINS = ("state_gain", "velocity_from_position_gain", "velocity_from_velocity_gain")


def train_policy(task, epochs: int, seed: int, device: str = "cpu"):
    """SHAC trained for ``epochs`` epochs on Newton (16 envs, h 16): the policy whose stochastic
    actions drive the policy-driven samples (on either engine: both simulate the same task)."""
    from algorithms.actor_critic import FirstOrderActorCritic
    from algorithms.config import preset
    from harness.envs import make_env

    torch.manual_seed(seed)
    cfg = preset("shac").replace(num_envs=16, horizon=16, max_epochs=epochs)
    env = make_env(task, "newton", cfg.num_envs, device, seed, cfg.horizon)
    algo = FirstOrderActorCritic(cfg, env.obs_dim, env.action_dim)
    env.reset()
    for _ in range(epochs):
        algo.train_epoch(env)
    return algo


def contact_predicate(mjw_sim, model):
    """``in_contact(q, qd, action)``: whether MuJoCo C (``model``, the task's on ``mjw_sim``) finds a
    contact stepping one env's state through that action's control step (the samplers' filter)."""
    task, n = mjw_sim.task, mjw_sim.num_envs

    def in_contact(q, qd, action) -> bool:
        engine = mjw_sim.state_from_generalized(q.expand(n, -1), qd.expand(n, -1)).engine[0].detach()
        return classify_step(mjw_sim, model, engine, task.actions_to_control(action)[0])["contacts"] > 0

    return in_contact


def sample_contact_states(
    sim, count: int, settle: int, stride: int, seed: int, action_scale: float, in_contact, policy=None
):
    """(q, qd, actions) of ``count`` states in contact from the env's own dynamics (an env that
    terminates is reset, as in training): every env settles ``settle`` zero-action steps, then acts,
    with random actions U(-s, s), or with ``policy``'s stochastic actions when given; every
    ``stride`` steps each env's state, and the action taken there, is kept if
    ``in_contact(q, qd, action)`` says so."""
    from tasks.env import TaskEnv

    env = TaskEnv(sim.task, sim)
    gen = torch.Generator().manual_seed(seed)
    env.reset()
    zeros = torch.zeros(sim.num_envs, sim.task.action_dim)
    qs, qds, acts = [], [], []
    with torch.no_grad():
        for _ in range(settle):
            env.step(zeros)
        step = 0
        while len(qs) < count:
            if policy is None:
                actions = action_scale * (2.0 * torch.rand(sim.num_envs, sim.task.action_dim, generator=gen) - 1.0)
            else:
                actions = policy.act(env.obs, deterministic=False)
            if step % stride == 0:
                q, qd = sim.state.joint_q.detach().clone(), sim.state.joint_qd.detach().clone()
                for i in range(sim.num_envs):
                    if len(qs) < count and in_contact(q[i : i + 1], qd[i : i + 1], actions[i : i + 1]):
                        qs.append(q[i])
                        qds.append(qd[i])
                        acts.append(actions[i])
            env.step(actions)
            step += 1
            if step > 200 * count:
                raise RuntimeError(f"{sim.task.name}: found {len(qs)} of {count} states in contact")
    return torch.stack(qs), torch.stack(qds), torch.stack(acts)


def compare(jac: np.ndarray, ref: np.ndarray) -> tuple[float, float]:
    """(relative Frobenius error, cosine) of ``jac`` against ``ref``."""
    a, b = jac.ravel().astype(np.float64), ref.ravel().astype(np.float64)
    nb = float(np.linalg.norm(b))
    rel = float(np.linalg.norm(a - b) / nb) if nb > 0 else math.inf
    denom = float(np.linalg.norm(a)) * nb
    return rel, float(a @ b / denom) if denom > 0 else math.nan


def _batches(n: int, *tensors: torch.Tensor):
    """(count, batch) pairs of ``n`` rows of every tensor, the last batch padded with copies of its
    first row so that every batch fills the sim's ``n`` envs; ``count`` rows of it are real."""
    total = tensors[0].shape[0]
    for start in range(0, total, n):
        count = min(n, total - start)
        pad = n - count
        yield (
            count,
            [torch.cat((t[start : start + count], t[start : start + 1].expand(pad, *t.shape[1:]))) for t in tensors],
        )


def gains(state_jac: np.ndarray, nq: int, position_cols: list[int], velocity_cols: list[int]) -> dict:
    """Spectral norms of a step's state Jacobian (rows: next ``[q, qd]``; ``nq`` rows of positions)
    over the given position and velocity columns, and of its two velocity-row blocks."""
    cols = position_cols + velocity_cols
    return {
        "state_gain": float(np.linalg.norm(state_jac[:, cols], 2)),
        "velocity_from_position_gain": float(np.linalg.norm(state_jac[nq:, position_cols], 2)),
        "velocity_from_velocity_gain": float(np.linalg.norm(state_jac[nq:, velocity_cols], 2)),
    }


def tangent_gain_columns(layout) -> tuple[list[int], list[int]]:
    """MuJoCo-Warp's tangent state columns that :func:`gains` reads: positions without the root's
    rotation (tangent 3:6; Newton's columns leave out its quaternion), then velocities."""
    nv = layout.nv
    return [j for j in range(nv) if not (layout.floating_base and 3 <= j < 6)], list(range(nv, 2 * nv))


def _mujoco_warp_rows(sim, model, q, qd, actions, progress) -> list[dict]:
    from backends.mujoco_warp.reference import float64_step_jacobians

    layout = sim.layout
    position_cols, velocity_cols = tangent_gain_columns(layout)
    rows = []
    for count, (qb, qdb, ab) in _batches(sim.num_envs, q, qd, actions):
        engine = sim.state_from_generalized(qb, qdb).engine.detach()
        control = sim.task.actions_to_control(ab)
        _, jac_state, jac_control = sim.step_jacobians(engine, control)
        for i in range(count):
            _, ref_state, ref_control = float64_step_jacobians(sim, engine[i], control[i], model=model)
            jac = np.concatenate((jac_state[i].numpy(), jac_control[i].numpy()), axis=1)
            rel, cos = compare(jac, np.concatenate((ref_state, ref_control), axis=1))
            reference = gains(ref_state, layout.nq, position_cols, velocity_cols)
            rows.append(
                {
                    "rel_error": rel,
                    "cosine": cos,
                    **gains(jac_state[i].numpy().astype(np.float64), layout.nq, position_cols, velocity_cols),
                    **{f"reference_{k}": v for k, v in reference.items()},
                    **classify_step(sim, model, engine[i], control[i]),
                }
            )
        progress(f"  {len(rows)}/{q.shape[0]} states")
    return rows


# -- Newton: the tape against a step-size sweep ---------------------------------------------------
def _input_columns(layout) -> torch.Tensor:
    """Indices of (q, qd) whose perturbation stays a valid state: all but the root quaternion."""
    total = layout.nq + layout.nv
    skip = set(range(3, 7)) if layout.floating_base else set()
    return torch.tensor([i for i in range(total) if i not in skip])


def _newton_rows(sim, mjw_sim, model, q, qd, actions, eps_sweep, progress) -> list[dict]:
    layout = sim.layout
    nq = layout.nq
    cols = _input_columns(layout)
    n = sim.num_envs
    rows = []

    def step(x_state: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        state = sim.state_from_generalized(x_state[:, :nq], x_state[:, nq:])
        nxt = sim.advance(state, a)
        return torch.cat((nxt.joint_q, nxt.joint_qd), dim=1)

    # the tape's columns: positions (root quaternion left out) then velocities
    position_cols = [j for j, c in enumerate(cols.tolist()) if c < nq]
    velocity_cols = [j for j, c in enumerate(cols.tolist()) if c >= nq]
    for count, (qb, qdb, ab) in _batches(n, q, qd, actions):
        x = torch.cat((qb, qdb), dim=1).detach()
        a = ab.detach()
        # the tape: one backward pass per output coordinate, every env at once (envs are independent)
        xs, av = x.clone().requires_grad_(True), a.clone().requires_grad_(True)
        out = step(xs, av)
        tape = torch.zeros(n, out.shape[1], cols.numel() + a.shape[1], dtype=torch.float64)
        for d in range(out.shape[1]):
            gx, ga = torch.autograd.grad(out[:, d].sum(), (xs, av), retain_graph=d + 1 < out.shape[1])
            tape[:, d] = torch.cat((gx[:, cols], ga), dim=1).double()
        fds = []
        with torch.no_grad():
            for eps in eps_sweep:
                fd = torch.zeros_like(tape)
                for j in range(cols.numel() + a.shape[1]):
                    if j < cols.numel():
                        plus, minus = x.clone(), x.clone()
                        plus[:, cols[j]] += eps
                        minus[:, cols[j]] -= eps
                        diff = step(plus, a) - step(minus, a)
                    else:
                        plus, minus = a.clone(), a.clone()
                        plus[:, j - cols.numel()] += eps
                        minus[:, j - cols.numel()] -= eps
                        diff = step(x, plus) - step(x, minus)
                    fd[:, :, j] = diff.double() / (2.0 * eps)
                fds.append(fd)
        engine = mjw_sim.state_from_generalized(x[:, :nq], x[:, nq:]).engine.detach()
        control = mjw_sim.task.actions_to_control(a)
        for i in range(count):
            per_eps = [compare(tape[i].numpy(), fd[i].numpy()) for fd in fds]
            # a plateau: two neighbouring step sizes whose differences agree; the tape against the
            # first such pair's smaller step
            plateau = None
            for k in range(len(fds) - 1):
                if compare(fds[k][i].numpy(), fds[k + 1][i].numpy())[0] < PLATEAU:
                    plateau = k + 1
                    break
            rel, cos = per_eps[plateau] if plateau is not None else min(per_eps)
            rows.append(
                {
                    "rel_error": rel,
                    "cosine": cos,
                    "plateau_eps": eps_sweep[plateau] if plateau is not None else None,
                    "rel_error_per_eps": [e for e, _ in per_eps],
                    **gains(tape[i].numpy(), nq, position_cols, velocity_cols),
                    **classify_step(mjw_sim, model, engine[i], control[i]),
                }
            )
        progress(f"  {len(rows)}/{q.shape[0]} states")
    return rows


# -- the check --------------------------------------------------------------------------------------
def _summary(rows: list[dict]) -> dict:
    if not rows:
        return {"states": 0}
    rel = np.array([r["rel_error"] for r in rows])
    cos = np.array([r["cosine"] for r in rows], dtype=float)
    out = {
        "states": len(rows),
        "median_rel_error": float(np.median(rel)),
        "median_cosine": float(np.nanmedian(cos)) if np.isfinite(cos).any() else math.nan,
    }
    for t in THRESHOLDS:
        out[f"within_{round(t * 100)}pct"] = float(np.mean(rel <= t))
    for key in GAINS:
        for name in (key, f"reference_{key}"):
            if name in rows[0]:
                out[f"median_{name}"] = float(np.median([r[name] for r in rows]))
    return out


def _sample_sources(sim, sources, sampling) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, list[str]]:
    """States in contact from each ``(label, count, policy)`` source (None: random actions), stacked,
    with each state's source label."""
    settle, stride, seed, action_scale, in_contact = sampling
    parts = [
        sample_contact_states(sim, n, settle, stride, seed, action_scale, in_contact, policy) + (label,)
        for label, n, policy in sources
    ]
    q, qd, actions = (torch.cat([p[k] for p in parts]) for k in range(3))
    return q, qd, actions, [p[3] for p in parts for _ in range(p[0].shape[0])]


def _classes(rows: list[dict]) -> dict[str, list[dict]]:
    """The states of each class the summary separates (a state may be in several)."""
    resting = [r for r in rows if r["contacts"] > 0 and not r["onset"] and not r["limit"]]
    return {
        "contact made or broken in the step": [r for r in rows if r["onset"]],
        "joint limit active": [r for r in rows if r["limit"]],
        "friction slides (some contact at the cone)": [r for r in rows if r["sliding"]],
        "friction sticks (every contact inside the cone)": [r for r in rows if r["sticking"]],
        "contact, no onset, no limit": resting,
        "no onset, no limit, friction sticks": [r for r in resting if r["sticking"]],
    }


def contact_jacobians(
    task_name: str,
    backend: str,
    states: int = 200,
    num_envs: int = 8,
    settle: int = 30,
    stride: int = 5,
    seed: int = 0,
    action_scale: float = 0.5,
    policy_epochs: int = 30,
    preset: str | None = None,
    device: str = "cpu",
    eps_sweep=NEWTON_EPS,
    options: dict | None = None,
    progress=print,
) -> dict:
    """The check (module docstring): a summary over all states, per class and per source, and every
    state's row. ``policy_epochs`` 0 samples every state under random actions; ``options`` are the
    checked adapter's (for MuJoCo-Warp, its finite-difference settings)."""
    import backends
    from tasks import make_task

    reference_kind = backends.get(backend).contact_reference
    task = make_task(task_name, preset=preset)
    if task.layout.num_particles:
        raise ValueError(f"{task_name}: soft bodies have no MuJoCo C reference; use crosscheck")
    sim = make_sim(backend, task, num_envs, device=device, seed=seed, horizon=4, **(options or {}))
    try:  # MuJoCo's model of the task finds the contacts (and is the reference of MuJoCo's own adapters)
        mjw_sim = sim if reference_kind == "mujoco_c" else make_sim("mujoco_warp", task, num_envs, seed=seed, horizon=4)
    except (BackendError, ValueError, TypeError) as exc:
        raise ValueError(f"contact-jacobians finds contacts with MuJoCo's model of the task: {exc}") from None
    model = accurate_model(mjw_sim.mjm)

    in_contact = contact_predicate(mjw_sim, model)
    sources = [("random actions", states - states // 2 if policy_epochs else states, None)]
    if policy_epochs and states // 2:
        progress(f"training the sampling policy: SHAC, {policy_epochs} epochs on newton")
        policy = train_policy(task, policy_epochs, seed)
        sources.append((f"SHAC policy after {policy_epochs} epochs", states // 2, policy))
    sampling = (settle, stride, seed, action_scale, in_contact)
    q, qd, actions, labels = _sample_sources(sim, sources, sampling)
    lifted = q.clone()
    if task.layout.floating_base:
        lifted[:, 2] = task.airborne_height
    if reference_kind == "mujoco_c":
        reference = "MuJoCo C float64, central differences (step 1e-6), solver tolerance 0"

        def check(q_, label):
            progress(label)
            return _mujoco_warp_rows(sim, model, q_, qd, actions, progress)
    else:
        reference = f"central differences in float32 over steps {list(eps_sweep)}, at the first plateau"

        def check(q_, label, checked=sim):
            progress(label)
            return _newton_rows(checked, mjw_sim, model, q_, qd, actions, eps_sweep, progress)

    rows = check(q, "states in contact:")
    for row, label in zip(rows, labels, strict=True):
        row["source"] = label
    control = check(lifted, f"the same states lifted to {task.airborne_height} m (control):")
    undamped = None
    if reference_kind == "differences" and task.physics.contact_kd > 0:
        # the penalty law damps only while a contact closes (min(v_n, 0) kd): a kink at v_n = 0 that a
        # resting foot sits on; without it the step is smooth in contact and the tape must agree
        smooth = make_task(task_name, dataclasses.replace(task.physics, contact_kd=0.0), preset=preset)
        smooth_sim = make_sim(backend, smooth, num_envs, device=device, seed=seed, horizon=4, **(options or {}))
        undamped = check(q, "the same states without contact damping (control):", smooth_sim)
    result = {
        "task": task_name,
        "backend": backend,
        "reference": reference,
        "sampling": {
            "states": states,
            "num_envs": num_envs,
            "settle": settle,
            "stride": stride,
            "action_scale": action_scale,
            "policy_epochs": policy_epochs,
            "seed": seed,
        },
        "options": dict(options or {}),
        "all": _summary(rows),
        "by_source": {label: _summary([r for r in rows if r["source"] == label]) for label, _, _ in sources},
        "by_class": {name: _summary(members) for name, members in _classes(rows).items()},
        "control_lifted": _summary(control),
        "control_no_contact_damping": _summary(undamped) if undamped is not None else None,
        "control_in_contact": sum(r["contacts"] > 0 for r in control),
        "rows": rows,
    }
    if reference_kind == "differences":
        plateaus = [r["plateau_eps"] for r in rows]
        result["plateau_fraction"] = float(np.mean([p is not None for p in plateaus]))
        result["median_rel_error_per_eps"] = {
            f"{eps:g}": float(np.median([r["rel_error_per_eps"][k] for r in rows])) for k, eps in enumerate(eps_sweep)
        }
    return result


def table(result: dict) -> str:
    """Markdown: the summary and the per-class rows."""
    lines = [f"{result['task']} on {result['backend']}: reference {result['reference']}", ""]

    def row(label, s):
        if not s["states"]:
            return [label, "0", "", "", "", ""]
        return [
            label,
            str(s["states"]),
            f"{s['median_rel_error']:.3g}",
            f"{s['median_cosine']:.4f}",
            f"{s['within_5pct']:.0%}",
            f"{s['within_20pct']:.0%}",
        ]

    rows = [row("all in contact", result["all"])]
    rows += [row(f"from {name}", s) for name, s in result.get("by_source", {}).items()]
    rows += [row(name, s) for name, s in result["by_class"].items()]
    rows.append(row("control: the same states lifted clear of the ground", result["control_lifted"]))
    if result.get("control_no_contact_damping"):
        rows.append(row("control: the same states, contact damping off", result["control_no_contact_damping"]))
    header = ["states", "n", "median rel. error", "median cosine", "within 5%", "within 20%"]
    lines += markdown_table(header, rows)
    a = result["all"]
    if "median_state_gain" in a:

        def gain_line(prefix):
            return ", ".join(
                f"{k.replace('_', ' ')} {a[f'median_{prefix}{k}']:.3g}" for k in GAINS if f"median_{prefix}{k}" in a
            )

        lines += [
            "",
            f"Median spectral norms in contact (the step's amplification of a state perturbation): {gain_line('')}.",
        ]
        if "median_reference_state_gain" in a:
            lines.append(f"The reference's at the same states: {gain_line('reference_')}.")
    if "plateau_fraction" in result:
        per_eps = ", ".join(f"{k}: {v:.3g}" for k, v in result["median_rel_error_per_eps"].items())
        lines += [
            "",
            f"States with a finite-difference plateau: {result['plateau_fraction']:.0%}; median relative "
            f"error of the tape against each step size: {per_eps}.",
        ]
    return "\n".join(lines) + "\n"


# -- the verb and its line in the suite's checks table ---------------------------------------------


def verb(args) -> int:
    """``python -m harness contact-jacobians``: per-step Jacobians in contact against a reference."""
    from harness.inputs import BadInput, preflight
    from harness.results import write_check_and_table

    memory = (args.num_envs, 1)
    preflight(
        backends=args.backend, task=args.task, device=args.device, preset=args.preset, out=args.out, memory=memory
    )
    try:
        result = contact_jacobians(
            args.task,
            args.backend,
            device=args.device,
            states=args.states,
            num_envs=args.num_envs,
            stride=args.stride,
            policy_epochs=args.policy_epochs,
            seed=args.seed,
            preset=args.preset,
            options=dict(args.backend_option or []),
            progress=lambda line: print(line, flush=True),
        )
    except (ValueError, BackendError) as exc:  # a task or an option the adapter cannot take
        raise BadInput(str(exc)) from None
    text = table(result)
    print(text)
    if args.out:
        for path in write_check_and_table(args.out, "contact-jacobians", result, text):
            print(f"wrote {path}")
    return 0


def summary(result: dict, kind: str) -> str:
    from harness.formatting import fmt, fmt_pct

    a, c = result.get("all", {}), result.get("control_lifted", {})
    return (
        f"Jacobians at {a.get('states')} states in contact: median rel. error {fmt(a.get('median_rel_error'))}, "
        f"{fmt_pct(a.get('within_20pct'))} within 20%; lifted control {fmt(c.get('median_rel_error'))}"
        + (f"; median state gain {fmt(a['median_state_gain'])}" if "median_state_gain" in a else "")
    )
