"""A corpus of malformed bench specs: every one is refused before any job starts, with one line naming
the key and what is valid (harness/suite/schema.py), through the API (``RunError``) and, for a sample,
through the command line (exit 2, nothing written)."""

from __future__ import annotations

import copy
import math

import pytest

from harness.cli import main
from harness.results import RunError
from harness.suite.bench import load_spec, plan

VALID = {
    "suite": {"name": "x", "jobs": 1},
    "eval": {"seeds": 1},
    "train": [{"backends": ["newton"], "tasks": ["ant"], "algos": ["shac"], "epochs": 1, "num_envs": 4}],
    "check": [{"kind": "gradcheck", "backends": ["newton"], "tasks": ["ant"], "args": ["--steps", "2"]}],
    "sim_to_sim": [{"task": "ant", "train_backend": "newton", "eval_backend": "mujoco_warp", "horizon": 32}],
    "landscape": [{"task": "ant", "backend": "newton", "horizon": 32, "grid": 3, "span": 0.5}],
}
DROP = object()

# (where: a path of keys and block indexes, the bad value or DROP, a word the one-line error must hold)
CASES = [
    # [suite]
    (("suite", "name"), DROP, "needs name"),
    (("suite", "name"), "../escape", "a name of letters"),
    (("suite", "name"), "a/b", "a name of letters"),
    (("suite", "name"), "", "non-empty string"),
    (("suite", "name"), 3, "non-empty string"),
    (("suite", "name"), ".hidden", "a name of letters"),
    (("suite", "name"), "x" * 300, "a name of letters"),
    (("suite", "jobs"), 0, "[suite] jobs"),
    (("suite", "jobs"), "2", "an integer"),
    (("suite", "jobs"), True, "an integer"),
    (("suite", "jobs"), 1.5, "an integer"),
    (("suite", "device"), "tpu", "unknown 'tpu'"),
    (("suite", "device"), "cuda:7", "unknown 'cuda:7'"),
    (("suite", "order"), "random", "choose from: seed, block"),
    (("suite", "colour"), "red", "unknown key(s) colour"),
    (("suite",), "x", "expected a table"),
    (("suite",), DROP, "needs suite"),
    # [eval]
    (("eval", "seeds"), -1, "[eval] seeds"),
    (("eval", "seeds"), 1.5, "an integer"),
    (("eval", "seeds"), True, "an integer"),
    (("eval", "num_envs"), 0, "[eval] num_envs"),
    (("eval", "max_steps"), 0, "[eval] max_steps"),
    (("eval", "max_steps"), "300", "an integer"),
    (("eval", "episodes"), 3, "unknown key(s) episodes"),
    (("eval",), [1], "expected a table"),
    # [[train]]
    (("train",), {"backends": "newton"}, "an array of tables"),
    (("train",), "x", "an array of tables"),
    (("train", 0, "backends"), [], "a non-empty list"),
    (("train", 0, "backends"), "bullet", "unknown 'bullet'"),
    (("train", 0, "backends"), ["newton", "newton"], "without repeats"),
    (("train", 0, "backends"), [3], "non-empty string"),
    (("train", 0, "backends"), DROP, "needs backends"),
    (("train", 0, "tasks"), "dog", "unknown 'dog'"),
    (("train", 0, "tasks"), [], "a non-empty list"),
    (("train", 0, "tasks"), {"ant": 1}, "non-empty string"),
    (("train", 0, "tasks"), DROP, "needs tasks"),
    (("train", 0, "algos"), ["ppo"], "unknown 'ppo'"),
    (("train", 0, "algos"), "shac,sapo", "unknown 'shac,sapo'"),
    (("train", 0, "algos"), DROP, "needs algos"),
    (("train", 0, "seeds"), -1, "an integer in [0"),
    (("train", 0, "seeds"), 1.5, "an integer"),
    (("train", 0, "seeds"), True, "an integer"),
    (("train", 0, "seeds"), "0", "an integer"),
    (("train", 0, "seeds"), 2**64 - 1, "an integer in [0, 2147483647]"),
    (("train", 0, "seeds"), [0, 0], "without repeats"),
    (("train", 0, "seeds"), [], "a non-empty list"),
    (("train", 0, "seeds"), [0, -2], "seeds[1]"),
    (("train", 0, "horizons"), 0, "horizons"),
    (("train", 0, "horizons"), [-3], "horizons[0]"),
    (("train", 0, "horizons"), "32", "an integer"),
    (("train", 0, "horizons"), [32, 32], "without repeats"),
    (("train", 0, "horizons"), 1.5, "an integer"),
    (("train", 0, "epochs"), 0, "epochs"),
    (("train", 0, "epochs"), -1, "epochs"),
    (("train", 0, "epochs"), True, "an integer"),
    (("train", 0, "epochs"), "3", "an integer"),
    (("train", 0, "epochs"), 1.5, "an integer"),
    (("train", 0, "epochs"), 10**7, "an integer in [1, 1000000]"),
    (("train", 0, "epochs"), DROP, "needs epochs"),
    (("train", 0, "num_envs"), 0, "num_envs"),
    (("train", 0, "num_envs"), "64", "an integer"),
    (("train", 0, "num_envs"), True, "an integer"),
    (("train", 0, "num_envs"), 10**6, "an integer in [1, 65536]"),
    (("train", 0, "eval"), {"seeds": -1}, "eval seeds"),
    (("train", 0, "eval"), {"num_envs": 0}, "eval num_envs"),
    (("train", 0, "eval"), {"runs": 2}, "unknown key(s) runs"),
    (("train", 0, "eval"), 3, "expected a table"),
    (("train", 0, "per_task"), {"go2": {"epochs": 2}}, "'go2' is not one of the block's tasks"),
    (("train", 0, "per_task"), {"ant": {"epochs": 0}}, "per_task.ant epochs"),
    (("train", 0, "per_task"), {"ant": {"algos": ["sapo"]}}, "unknown key(s) algos"),
    (("train", 0, "per_task"), {"ant": 3}, "expected a table"),
    (("train", 0, "per_task"), [1], "expected a table"),
    (("train", 0, "preset"), 3, "non-empty string"),
    (("train", 0, "preset"), "", "non-empty string"),
    (("train", 0, "preset"), "stiff", "unknown physics preset of ant 'stiff'"),
    (("train", 0, "backend_options"), {"mujoco_warp": {"fd_scheme": "central"}}, "not one of the block's backends"),
    (("train", 0, "backend_options"), {"newton": {"solver": [1]}}, "a string or a number"),
    (("train", 0, "backend_options"), {"newton": {"graph_capture": True}}, "a string or a number"),
    (("train", 0, "backend_options"), {"newton": 1}, "a table of option = value"),
    (("train", 0, "hyperparameters"), "fast", "expected a table"),
    (("train", 0, "hyperparameters"), {"gamma": 1.5}, "bad configuration"),
    (("train", 0, "hyperparameters"), {"warp_speed": 9}, "bad configuration"),
    (("train", 0, "num_env"), 4, "unknown key(s) num_env"),
    # [[check]]
    (("check", 0, "kind"), "lint", "unknown 'lint'"),
    (("check", 0, "kind"), 3, "non-empty string"),
    (("check", 0, "kind"), DROP, "needs kind"),
    (("check", 0, "backends"), [], "a non-empty list"),
    (("check", 0, "backends"), ["bullet"], "unknown backend"),
    (("check", 0, "backends"), DROP, "needs backends"),
    (("check", 0, "tasks"), "dog", "unknown 'dog'"),
    (("check", 0, "tasks"), DROP, "needs tasks"),
    (("check", 0, "args"), "--steps 2", "a list of command-line words"),
    (("check", 0, "args"), [True], "a string or a number"),
    (("check", 0, "args"), [["--steps"]], "a string or a number"),
    (("check", 0, "per_task"), {"go2": {"args": []}}, "'go2' is not one of the block's tasks"),
    (("check", 0, "per_task"), {"ant": {"flags": []}}, "unknown key(s) flags"),
    (("check", 0, "per_task"), "x", "expected a table"),
    (("check", 0, "tolerance"), 0.1, "unknown key(s) tolerance"),
    (("check",), [3], "expected a table"),
    # [[sim_to_sim]]
    (("sim_to_sim", 0, "eval_backend"), "newton", "both 'newton'"),
    (("sim_to_sim", 0, "eval_backend"), "bullet", "unknown 'bullet'"),
    (("sim_to_sim", 0, "eval_backend"), DROP, "needs eval_backend"),
    (("sim_to_sim", 0, "train_backend"), DROP, "needs train_backend"),
    (("sim_to_sim", 0, "task"), DROP, "needs task"),
    (("sim_to_sim", 0, "task"), "dog", "unknown 'dog'"),
    (("sim_to_sim", 0, "eval_seeds"), 0, "eval_seeds"),
    (("sim_to_sim", 0, "eval_seeds"), -1, "eval_seeds"),
    (("sim_to_sim", 0, "num_envs"), 0, "num_envs"),
    (("sim_to_sim", 0, "max_steps"), 0, "max_steps"),
    (("sim_to_sim", 0, "algos"), [], "a non-empty list"),
    (("sim_to_sim", 0, "algos"), ["ppo"], "unknown 'ppo'"),
    (("sim_to_sim", 0, "seeds"), [-1], "seeds[0]"),
    (("sim_to_sim", 0, "horizon"), 0, "horizon"),
    (("sim_to_sim", 0, "horizon"), 16, "selects no run"),
    (("sim_to_sim", 0, "epochs"), 0, "epochs"),
    (("sim_to_sim", 0, "epochs"), 7, "selects no run"),
    (("sim_to_sim", 0, "train_num_envs"), 0, "train_num_envs"),
    (("sim_to_sim", 0, "backend_options"), {"fd_scheme": ["x"]}, "a string or a number"),
    (("sim_to_sim", 0, "protocol"), "paper", "unknown key(s) protocol"),
    # [[landscape]]
    (("landscape", 0, "grid"), 0, "grid"),
    (("landscape", 0, "grid"), 1, "an integer in [2, 400]"),
    (("landscape", 0, "grid"), 1000, "an integer in [2, 400]"),
    (("landscape", 0, "grid"), "40", "an integer"),
    (("landscape", 0, "span"), 0, "span"),
    (("landscape", 0, "span"), -1.0, "span"),
    (("landscape", 0, "span"), "1", "a finite number"),
    (("landscape", 0, "span"), math.nan, "a finite number"),
    (("landscape", 0, "span"), math.inf, "a finite number"),
    (("landscape", 0, "num_envs"), 0, "num_envs"),
    (("landscape", 0, "backend"), DROP, "needs backend"),
    (("landscape", 0, "backend"), "mujoco_warp", "selects no run"),
    (("landscape", 0, "algos"), ["sapo"], "selects no run"),
    (("landscape", 0, "seeds"), [True], "an integer"),
    (("landscape", 0, "resolution"), 40, "unknown key(s) resolution"),
    # [[render]]
    (("render",), [{"task": "ant", "backend": "newton", "horizon": 32, "frames": 0}], "[[render]] #1 frames"),
    (("render",), [{"task": "ant", "backend": "newton", "horizon": 32, "compare": "yes"}], "true or false"),
    (("render",), [{"task": "ant", "backend": "newton", "horizon": 32, "max_steps": -5}], "max_steps"),
    (("render",), [{"task": "ant", "backend": "newton", "horizon": 16}], "selects no run"),
    (("render",), [{"task": "ant", "horizon": 32}], "needs backend"),
    # the top level
    (("report",), {"format": "html"}, "unknown key(s) report"),
    (("sim2sim",), [], "unknown key(s) sim2sim"),
]


def _mutated(where: tuple, value) -> dict:
    data = copy.deepcopy(VALID)
    *parents, last = where
    target = data
    for key in parents:
        target = target[key]
    if value is DROP:
        del target[last]
    else:
        target[last] = value
    return data


def test_the_valid_spec_plans(tmp_path):
    assert plan(copy.deepcopy(VALID), tmp_path)


@pytest.mark.parametrize(
    "where, value, needle",
    CASES,
    ids=[" ".join(map(str, c[0])) + ("=DROP" if c[1] is DROP else f"={c[1]!r}"[:40]) for c in CASES],
)
def test_a_malformed_spec_is_refused_in_one_line(where, value, needle, tmp_path):
    with pytest.raises(RunError) as info:
        plan(_mutated(where, value), tmp_path)
    message = str(info.value)
    assert "\n" not in message and needle in message, message
    assert not any(tmp_path.iterdir()), "planning wrote a file"


FILE_CASES = [
    ("not TOML", b"[suite\nname = 'x'\n", "not valid TOML"),
    ("not UTF-8", b"[suite]\nname = '\xff\xfe'\n", "not UTF-8"),
    ("a string for an integer", b"[suite]\nname='x'\njobs='2'\n", "[suite] jobs"),
    ("a suite name that climbs out", b"[suite]\nname='..'\n", "a name of letters"),
    (
        "epochs = true",
        b"[suite]\nname='x'\n[[train]]\nbackends='newton'\ntasks='ant'\nalgos='shac'\nepochs=true\n",
        "an integer",
    ),
    ("eval seeds of -1", b"[suite]\nname='x'\n[eval]\nseeds=-1\n", "[eval] seeds"),
]


@pytest.mark.parametrize("case, content, needle", FILE_CASES, ids=[c[0] for c in FILE_CASES])
def test_a_malformed_spec_file_exits_2_and_writes_nothing(case, content, needle, tmp_path, capsys):
    spec = tmp_path / "spec.toml"
    spec.write_bytes(content)
    store = tmp_path / "store"
    assert main(["bench", "--spec", str(spec), "--store", str(store)]) == 2, case
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and needle in err, err
    assert not store.exists()
    with pytest.raises(RunError):
        load_spec(spec_file=str(spec))


def test_the_corpus_with_the_command_lines_is_at_least_150_cases():
    from tests.test_bad_input import API_CASES, CLI_CASES

    assert len(CASES) + len(FILE_CASES) + len(CLI_CASES) + len(API_CASES) >= 150
