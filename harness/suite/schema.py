"""The bench suite's spec schema: every key of a spec typed, ranged and checked in one pass before the
planner (:func:`harness.suite.bench.plan`) or any job starts.

A spec is TOML (``harness/suite/bench.py``'s docstring lists its keys). :func:`validate_spec` walks it against
:data:`SCHEMA` and raises :class:`~harness.results.RunError` with one line naming the key's path
(``[[train]] #2 epochs``) and what is valid, for: a wrong type (a string for an integer, a boolean for a
number, a list given as a string, ``sequential = "yes"`` for true), a value out of range (epochs 0, a
landscape grid of 1, a seed of -1 or 2**64), an unknown key, a name that does not exist (backend, task,
algorithm, check kind), a suite name that would leave the store, and the cross-field rules: a per-task
block for a task its block does not train, options for a backend its block does not use, a sim-to-sim
pair on one backend. Names are checked against the registries; selections that match no run are the
planner's to refuse.

Limits: seeds are at most 2**31 - 1 (every generator the harness seeds takes them), env counts at most
65,536 per run, landscape grids at most 400 x 400.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable

from harness.bounds import (
    INT_MAX,
    MAX_ENVS,
    MAX_EPOCHS,
    MAX_EVAL_SEEDS,
    MAX_FRAMES,
    MAX_GRID,
    MAX_HORIZON,
    MAX_JOBS,
    MAX_SPAN,
    MAX_STEP_GAIN_STATES,
    MAX_STEPS,
    MAX_STRIDE,
)
from harness.results import RunError

NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")

Check = Callable[[object, str], None]


def _fail(path: str, what: str, value) -> None:
    shown = repr(value)
    raise RunError(f"{path}: expected {what}, got {shown if len(shown) <= 60 else shown[:57] + '...'}")


def integer(low: int, high: int = INT_MAX) -> Check:
    def check(value, path: str) -> None:
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            _fail(path, f"an integer in [{low}, {high}]", value)

    return check


def number(low: float, high: float = math.inf, low_open: bool = False) -> Check:
    def check(value, path: str) -> None:
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        ok = ok and (value > low if low_open else value >= low) and value <= high
        if not ok:
            _fail(
                path,
                f"a finite number {'>' if low_open else '>='} {low}" + (f", <= {high}" if high < math.inf else ""),
                value,
            )

    return check


def text(choices: Callable[[], list[str]] | tuple[str, ...] | None = None, pattern: re.Pattern | None = None) -> Check:
    def check(value, path: str) -> None:
        if not isinstance(value, str) or not value:
            _fail(path, "a non-empty string", value)
        valid = choices() if callable(choices) else choices
        if valid is not None and value not in valid:
            raise RunError(f"{path}: unknown {value!r}; choose from: {', '.join(valid)}")
        if pattern is not None and not pattern.match(value):
            _fail(path, f"a name of letters, digits, '_', '.', '-' (matching {pattern.pattern})", value)

    return check


def one_or_many(item: Check) -> Check:
    """A value or a non-empty list of values, each checked by ``item``, no repeats."""

    def check(value, path: str) -> None:
        values = value if isinstance(value, list) else [value]
        if not values:
            _fail(path, "a non-empty list", value)
        for k, v in enumerate(values):
            item(v, f"{path}[{k}]" if isinstance(value, list) else path)
        if len({repr(v) for v in values}) != len(values):
            _fail(path, "a list without repeats", value)

    return check


def boolean(value, path: str) -> None:
    if not isinstance(value, bool):
        _fail(path, "true or false", value)


def words(value, path: str) -> None:
    """A check's extra command-line words: a list of strings and numbers."""
    if not isinstance(value, list):
        _fail(path, "a list of command-line words", value)
    for k, w in enumerate(value):
        if isinstance(w, bool) or not isinstance(w, str | int | float):
            _fail(f"{path}[{k}]", "a string or a number", w)


def table(fields: dict[str, Check], required: tuple[str, ...] = ()) -> Check:
    def check(value, path: str) -> None:
        if not isinstance(value, dict):
            _fail(path, "a table", value)
        unknown = sorted(set(value) - set(fields))
        if unknown:
            raise RunError(f"{path}: unknown key(s) {', '.join(unknown)}; allowed: {', '.join(sorted(fields))}")
        for key in required:
            if key not in value:
                raise RunError(f"{path}: needs {key}")
        for key, v in value.items():
            fields[key](v, f"{path} {key}" if path else key)

    return check


def free_table(value, path: str) -> None:
    """A table whose keys another check owns (hyperparameters: the algorithm's config refuses bad ones)."""
    if not isinstance(value, dict):
        _fail(path, "a table", value)


def _backends() -> list[str]:
    import backends

    return backends.available()


def _tasks() -> list[str]:
    import tasks

    return tasks.available()


def _algos() -> list[str]:
    from algorithms.config import ALGORITHMS

    return list(ALGORITHMS)


def _check_kinds() -> list[str]:
    from harness.checks.kinds import CHECK_KINDS

    return list(CHECK_KINDS)


def _devices() -> list[str]:
    import torch

    return [
        "cpu",
        *(["cuda"] + [f"cuda:{i}" for i in range(torch.cuda.device_count())] if torch.cuda.is_available() else []),
    ]


def _options(value, path: str) -> None:
    """``{BACKEND = {OPTION = VALUE}}``: options of the block's backends, strings or numbers."""
    free_table(value, path)
    for backend, opts in value.items():
        if not isinstance(opts, dict):
            _fail(f"{path} {backend}", "a table of option = value", opts)
        for key, v in opts.items():
            if isinstance(v, bool) or not isinstance(v, str | int | float):
                _fail(f"{path} {backend} {key}", "a string or a number", v)


def _flat_options(value, path: str) -> None:
    """An analysis block's ``backend_options``: the selected runs' options, ``{OPTION = VALUE}``."""
    free_table(value, path)
    for key, v in value.items():
        if isinstance(v, bool) or not isinstance(v, str | int | float):
            _fail(f"{path} {key}", "a string or a number", v)


backend, task, algo = text(_backends), text(_tasks), text(_algos)
seed = integer(0)
EVAL = {"seeds": integer(0, MAX_EVAL_SEEDS), "num_envs": integer(1, MAX_ENVS), "max_steps": integer(1, MAX_STEPS)}
RUN_SETTINGS = {
    "epochs": integer(1, MAX_EPOCHS),
    "num_envs": integer(1, MAX_ENVS),
    "horizons": one_or_many(integer(1, MAX_HORIZON)),
    "seeds": one_or_many(seed),
    "hyperparameters": free_table,
    "preset": text(),
}
SELECTION = {
    "task": task,
    "algos": one_or_many(algo),
    "seeds": one_or_many(seed),
    "horizon": integer(1, MAX_HORIZON),
    "preset": text(),
    "epochs": integer(1, MAX_EPOCHS),
    "train_num_envs": integer(1, MAX_ENVS),
    "backend_options": _flat_options,
    "hyperparameters": free_table,  # the runs' own (an ablation's); none selects runs without any
}


def _per_task(value, path: str) -> None:
    free_table(value, path)
    for name, override in value.items():
        table(RUN_SETTINGS)(override, f"{path}.{name}")


def _check_per_task(value, path: str) -> None:
    free_table(value, path)
    for name, override in value.items():
        table({"args": words})(override, f"{path}.{name}")


TRAIN = table(
    {
        "backends": one_or_many(backend),
        "tasks": one_or_many(task),
        "algos": one_or_many(algo),
        **RUN_SETTINGS,
        "per_task": _per_task,
        "eval": table(EVAL),
        "backend_options": _options,
        "sequential": boolean,  # the seeds list is the most the pre-registered design may use (harness/suite/bench.py)
    },
    required=("backends", "tasks", "algos", "epochs"),
)
CHECK = table(
    {"kind": text(_check_kinds), "backends": one_or_many(text()), "tasks": one_or_many(task), "args": words}
    | {"per_task": _check_per_task},
    required=("kind", "backends", "tasks"),
)
SIM_TO_SIM = table(
    {**SELECTION, "train_backend": backend, "eval_backend": backend}
    | {"eval_seeds": integer(1, MAX_EVAL_SEEDS), "num_envs": integer(1, MAX_ENVS), "max_steps": integer(1, MAX_STEPS)},
    required=("task", "train_backend", "eval_backend"),
)
LANDSCAPE = table(
    {**SELECTION, "backend": backend, "grid": integer(2, MAX_GRID), "span": number(0.0, MAX_SPAN, low_open=True)}
    | {"num_envs": integer(1, MAX_ENVS)},
    required=("task", "backend"),
)
STEP_GAIN = table(
    {**SELECTION, "backend": backend, "states": integer(1, MAX_STEP_GAIN_STATES), "stride": integer(1, MAX_STRIDE)}
    | {"num_envs": integer(1, MAX_ENVS)},
    required=("task", "backend"),
)
RENDER = table(
    {**SELECTION, "backend": backend, "compare": boolean}
    | {"max_steps": integer(1, 10**5), "frames": integer(1, MAX_FRAMES)},
    required=("task", "backend"),
)
SUITE = table(
    {
        "name": text(pattern=NAME_PATTERN),
        "description": text(),
        "jobs": integer(1, MAX_JOBS),
        "device": text(_devices),
        "order": text(("seed", "block")),
    },
    required=("name",),
)


def _blocks(check: Check) -> Check:
    def each(value, path: str) -> None:
        if not isinstance(value, list):
            _fail(path, "an array of tables ([[...]])", value)
        for k, block in enumerate(value):
            check(block, f"{path} #{k + 1}")

    return each


SCHEMA = table(
    {
        "suite": SUITE,
        "eval": table(EVAL),
        "train": _blocks(TRAIN),
        "check": _blocks(CHECK),
        "sim_to_sim": _blocks(SIM_TO_SIM),
        "landscape": _blocks(LANDSCAPE),
        "step_gain": _blocks(STEP_GAIN),
        "render": _blocks(RENDER),
    },
    required=("suite",),
)


def validate_spec(data: dict, where: str = "spec") -> dict:
    """``data`` when every key of the spec is valid (module docstring); else one :class:`RunError` line."""
    if not isinstance(data, dict):
        _fail(where, "a TOML table", data)
    try:  # paths are rewritten as the TOML writes its tables: [suite] name, [[train]] #1 epochs
        SCHEMA(data, "")
    except RunError as exc:
        message = str(exc).removeprefix(": ")  # the top level's own path is empty
        message = re.sub(r"^(train|check|sim_to_sim|landscape|step_gain|render)\b", r"[[\1]]", message)
        message = re.sub(r"^(suite|eval)\b", r"[\1]", message)
        raise RunError(message if message.startswith("[") else f"{where}: {message}") from None
    for k, block in enumerate(data.get("train", [])):
        where_block = f"[[train]] #{k + 1}"
        trained = block["tasks"] if isinstance(block["tasks"], list) else [block["tasks"]]
        for name in block.get("per_task", {}):
            if name not in trained:
                raise RunError(f"{where_block} per_task.{name}: {name!r} is not one of the block's tasks")
        used = block["backends"] if isinstance(block["backends"], list) else [block["backends"]]
        for name in block.get("backend_options", {}):
            if name not in used:
                raise RunError(f"{where_block} backend_options: {name!r} is not one of the block's backends")
    for k, block in enumerate(data.get("check", [])):
        listed = block["tasks"] if isinstance(block["tasks"], list) else [block["tasks"]]
        for name in block.get("per_task", {}):
            if name not in listed:
                raise RunError(f"[[check]] #{k + 1} per_task.{name}: {name!r} is not one of the block's tasks")
    for k, block in enumerate(data.get("sim_to_sim", [])):
        if block["train_backend"] == block["eval_backend"]:
            raise RunError(
                f"[[sim_to_sim]] #{k + 1}: train_backend and eval_backend are both {block['eval_backend']!r}"
            )
    return data
