"""What every verb checks before work: the one-line refusal (:class:`BadInput`, exit 2) and the shared
validations of names, devices, presets, output paths and hyperparameters."""

from __future__ import annotations

import dataclasses

from harness.results import RunError, out_problem

EXIT_BAD_INPUT = 2


class BadInput(RunError):
    """User input we refuse: reported as one line, exit code 2. One family with
    :class:`harness.results.RunError` (a run folder's or a configuration's problem), which
    ``python -m harness`` reports the same way."""


def validate_names(backend: str | None = None, task: str | None = None) -> None:
    import backends
    import tasks
    from simcore import UnknownNameError  # the registries' own message, without loading an entry point

    for kind, name, choices in (("backend", backend, backends.available()), ("task", task, tasks.available())):
        if name is not None and name not in choices:
            raise BadInput(str(UnknownNameError(kind, name, choices)))


def check_device(device: str) -> None:
    from harness.envs import device_problem

    problem = device_problem(device)
    if problem:
        raise BadInput(problem)


def make_verb_sim(args, horizon: int):
    # Imports here, not at module level: `list` and argument errors must not load an engine.
    from harness.envs import make_sim
    from tasks import make_task

    try:
        options = dict(getattr(args, "backend_option", None) or [])
        task = make_task(args.task, preset=getattr(args, "preset", None))
        return make_sim(args.backend, task, args.num_envs, args.device, args.seed, horizon, **options)
    except (RuntimeError, ValueError) as exc:
        raise BadInput(f"cannot build {args.backend}/{args.task} on {args.device}: {exc}") from exc


def check_preset(task: str, preset: str | None) -> None:
    """Refuse a physics preset the task does not define, in one line naming the ones it does."""
    from tasks import UnknownPresetError, make_task

    try:
        make_task(task, preset=preset)
    except UnknownPresetError as exc:
        raise BadInput(str(exc)) from None


def check_memory(
    backends: str | list[str], task: str, num_envs: int, horizon: int = 0, device: str = "cpu", flag: str = "--num-envs"
) -> None:
    """Refuse ``num_envs`` (with gradients over ``horizon`` steps, 0: none) that cannot fit in this
    machine's memory on any of ``backends``: one line with the estimate and the limit."""
    from harness.resources import memory_problem

    for backend in [backends] if isinstance(backends, str) else backends:
        problem = memory_problem(backend, task, num_envs, horizon, grads=horizon > 0, device=device)
        if problem:
            raise BadInput(f"{flag} {num_envs}: {problem}")


def check_output(out: str, kind: str = "file") -> None:
    """A result file (or prefix of files; ``kind`` "folder": a directory) we may write
    (:func:`harness.results.out_problem`)."""
    problem = out_problem(out, kind)
    if problem:
        raise BadInput(problem)


_UNCHECKED = object()


def preflight(
    *,
    backends: str | list[str] | None = None,
    task: str | None = None,
    device: str | None = None,
    preset=_UNCHECKED,
    out: str | None = None,
    memory: tuple[int, int] | None = None,
) -> None:
    """The checks a verb declares, run before any work in the order a user would fix them: the backend
    and task names, the device, the task's physics ``preset``, the output file ``out`` and the
    ``memory`` of ``(num_envs, horizon)`` (horizon 0: no gradients) on every backend."""
    names = [backends] if isinstance(backends, str) else list(backends or [])
    for name in names:
        validate_names(backend=name)
    validate_names(task=task)
    if device is not None:
        check_device(device)
    if preset is not _UNCHECKED and task is not None:
        check_preset(task, preset)
    if out is not None:
        check_output(out)
    if memory is not None:
        check_memory(names, task, memory[0], memory[1], device or "cpu")


def algo_config(args, name: str):
    """The preset ``name`` with every hyperparameter flag the user gave applied (validated once)."""
    from algorithms.config import AlgoConfig, preset

    try:
        cfg = preset(name)
    except KeyError as exc:
        raise BadInput(exc.args[0]) from None
    changes = {}
    for f in dataclasses.fields(AlgoConfig):
        value = getattr(args, f.name, None)
        if value is not None and f.name != "algo":
            changes[f.name] = tuple(value) if isinstance(value, list) else value
    try:
        return cfg.replace(**changes)
    except ValueError as exc:
        raise BadInput(f"bad configuration: {exc}") from None


def out_stem(out: str) -> str:
    """``--out`` without a ``.json`` suffix: the stem of the files a verb writes beside its JSON (``.md``,
    ``.png``, ``.csv``); a suite passes the JSON's path, a user may pass either."""
    return out.removesuffix(".json")


def sim_physics(sim) -> dict:
    """What a check's result file says about the physics it ran: preset, constants, integrator, mapping."""
    return {**sim.task.physics_record(), "integrator": sim.integrator, "physics_mapping": sim.physics_mapping()}
