"""A corpus of malformed input: every case gets exit 2 (CLI) or a typed exception (API), one line naming
what is wrong and what is valid, no traceback, and nothing written or overwritten."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import pytest
import torch

import backends

pytest.importorskip("newton")

from backends import InvalidActionError, InvalidStateError, make  # noqa: E402
from harness.cli import main  # noqa: E402
from simcore import PhysicsSpec  # noqa: E402
from tasks import make_task  # noqa: E402

ANT = ["--task", "ant", "--backend", "newton"]
TRAIN = ["train", *ANT, "--algo", "shac", "--epochs", "1", "--num-envs", "4", "--horizon", "4"]


@pytest.fixture(scope="module")
def template(one_epoch_ant_run) -> Path:
    """A finished one-epoch run that each case copies and damages."""
    return one_epoch_ant_run


def _snapshot(root: Path) -> dict:
    return {p.relative_to(root): (p.read_bytes(), p.stat().st_mtime_ns) for p in root.rglob("*") if p.is_file()}


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: len(path.read_bytes()) // 2])


# (case id, args with RUN = a damaged copy of the template run and FILE = an existing file, damage)
CLI_CASES = [
    ("unknown verb", ["fly"], None, "invalid choice"),
    ("empty backend to render", ["render", "--run", "RUN", "--backend", ""], None, "expected a non-empty value"),
    ("empty parity output", ["parity", "--task", "ant", "--out", ""], None, "expected a non-empty value"),
    ("empty preset to train", [*TRAIN, "--preset", "", "--out", "new_run"], None, "expected a non-empty value"),
    ("empty fd-schemes output", ["fd-schemes", "--task", "ant", "--out", ""], None, "expected a non-empty value"),
    ("newline in an output name", [*TRAIN, "--out", "a\nb"], None, "expected one line"),
    ("no critic iterations", [*TRAIN, "--critic-iterations", "0", "--out", "new_run"], None, "critic_iterations"),
    (
        "an unreachable entropy target",
        [*[("sapo" if a == "shac" else a) for a in TRAIN], "--target-entropy-per-dim", "1e300", "--out", "new_run"],
        None,
        "target_entropy_per_dim must be in [-50, ln 2)",
    ),
    ("a second CPU", [*TRAIN, "--device", "cpu:1", "--out", "new_run"], None, "the CPU is one device here"),
    (
        "parity: a billion episode seeds",
        ["parity", "--task", "ant", "--episode-seeds", "1000000000"],
        None,
        "[1, 1000]",
    ),
    ("parity: a billion steps", ["parity", "--task", "ant", "--steps", "1000000000"], None, "[1, 10000]"),
    ("contact-jacobians: a billion states", ["contact-jacobians", *ANT, "--states", "1000000000"], None, "[1, 4096]"),
    ("landscape: a span of 1e30", ["landscape", "--run", "RUN", "--span", "1e30"], None, "(0, 100]"),
    ("render without a run", ["render", "--run", "nope"], None, "not a run directory"),
    (
        "render compare and backend",
        ["render", "--run", "RUN", "--compare", "--backend", "newton"],
        None,
        "drop --backend",
    ),
    ("render on an unknown backend", ["render", "--run", "RUN", "--backend", "bullet"], None, "unknown backend"),
    ("render without a policy", ["render", "--run", "RUN"], "missing_checkpoint", "has no checkpoint.pt"),
    ("render zero frames", ["render", "--run", "RUN", "--frames", "0"], None, "[1, 1000]"),
    ("train without --out", ["train", *ANT, "--algo", "shac", "--epochs", "1"], None, "needs --out"),
    (
        "unknown backend",
        ["train", "--task", "ant", "--backend", "bullet", "--algo", "shac", "--epochs", "1", "--out", "o"],
        None,
        "unknown backend",
    ),
    (
        "unknown task",
        ["train", "--task", "dog", "--backend", "newton", "--algo", "shac", "--epochs", "1", "--out", "o"],
        None,
        "unknown task",
    ),
    ("unknown algo", ["train", *ANT, "--algo", "ppo", "--epochs", "1", "--out", "o"], None, "unknown algorithm"),
    ("zero envs", [*TRAIN, "--num-envs", "0", "--out", "o"], None, "an integer in [1, 65536]"),
    ("text envs", [*TRAIN, "--num-envs", "many", "--out", "o"], None, "expected an integer"),
    ("negative horizon", [*TRAIN, "--horizon", "-1", "--out", "o"], None, "an integer in [1, 10000]"),
    (
        "zero epochs",
        ["train", *ANT, "--algo", "shac", "--epochs", "0", "--out", "o"],
        None,
        "an integer in [1, 1000000]",
    ),
    ("gamma above 1", [*TRAIN, "--gamma", "1.5", "--out", "o"], None, "gamma must be in (0, 1]"),
    ("gamma nan", [*TRAIN, "--gamma", "nan", "--out", "o"], None, "finite number"),
    ("lambda above 1", [*TRAIN, "--lam", "1.5", "--out", "o"], None, "lam must be in [0, 1]"),
    (
        "adaptive lambda of 1",
        ["train", *ANT, "--algo", "shac-tdadpt", "--epochs", "1", "--lam", "1", "--out", "o"],
        None,
        "lam must be in (0, 1)",
    ),
    ("fractional iterations", [*TRAIN, "--critic-iterations", "2.5", "--out", "o"], None, "expected an integer"),
    ("negative iterations", [*TRAIN, "--critic-iterations", "-1", "--out", "o"], None, "critic_iterations"),
    ("beta above 1", [*TRAIN, "--betas", "1.5", "0.9", "--out", "o"], None, "betas must lie in [0, 1)"),
    ("one beta", [*TRAIN, "--betas", "0.9", "--out", "o"], None, "expected 2 arguments"),
    ("negative learning rate", [*TRAIN, "--actor-lr", "-1", "--out", "o"], None, "actor_lr must be > 0"),
    ("negative min_lr", [*TRAIN, "--min-lr", "-1", "--out", "o"], None, "min_lr must be in"),
    (
        "negative skip threshold",
        [*TRAIN, "--max-grad-norm-skip", "-1", "--out", "o"],
        None,
        "max_grad_norm_skip must be > 0",
    ),
    ("zero clip", [*TRAIN, "--actor-grad-clip", "0", "--out", "o"], None, "actor_grad_clip must be > 0"),
    (
        "polyak above 1",
        [*TRAIN, "--target-critic-alpha", "1.5", "--out", "o"],
        None,
        "target_critic_alpha must be in [0, 1]",
    ),
    ("unknown return", [*TRAIN, "--actor-return", "gae", "--out", "o"], None, "invalid choice"),
    ("lambda every 1/0.3 epochs", [*TRAIN, "--lambda-iterations", "0.3", "--out", "o"], None, "1/k"),
    ("groups not dividing N", [*TRAIN, "--grad-var-groups", "3", "--out", "o"], None, "grad_var_groups"),
    ("zero hidden width", [*TRAIN, "--actor-hidden", "0", "--out", "o"], None, "hidden widths"),
    ("negative weight decay", [*TRAIN, "--weight-decay", "-0.1", "--out", "o"], None, "weight_decay must be >= 0"),
    ("bogus bool", [*TRAIN, "--obs-norm", "maybe", "--out", "o"], None, "true or false"),
    ("empty out", [*TRAIN, "--out", ""], None, "--out: expected a non-empty value"),
    ("out is a file", [*TRAIN, "--out", "FILE"], None, "is a file, not a directory"),
    ("out below a file", [*TRAIN, "--out", "FILE/run"], None, "is a file, not a directory"),
    ("out in an unwritable place", [*TRAIN, "--out", "/proc/diffsim-run"], None, "--out /proc/diffsim-run"),
    ("out holds a run", [*TRAIN, "--out", "RUN"], None, "already holds a run"),
    ("bogus device", [*TRAIN, "--device", "bogus", "--out", "o"], None, "unknown device"),
    ("cuda on a cpu machine", [*TRAIN, "--device", "cuda:0", "--out", "o"], "no_cuda", "no CUDA device"),
    ("text seed", [*TRAIN, "--seed", "abc", "--out", "o"], None, "expected an integer"),
    # sizes the types or the machine cannot hold, refused at the flag with the limit
    ("seed of 2**64", [*TRAIN, "--seed", str(2**64), "--out", "o"], None, "an integer in [0, 2147483647]"),
    ("negative seed", [*TRAIN, "--seed", "-1", "--out", "o"], None, "an integer in [0, 2147483647]"),
    ("ten million envs", [*TRAIN, "--num-envs", "10000000", "--out", "o"], None, "an integer in [1, 65536]"),
    ("a horizon of 1e5", [*TRAIN, "--horizon", "100000", "--out", "o"], None, "an integer in [1, 10000]"),
    ("epochs past 1e6", [*TRAIN, "--epochs", "2000000", "--out", "o"], None, "an integer in [1, 1000000]"),
    ("a landscape grid of 1", ["landscape", "--run", "RUN", "--grid", "1"], None, "an integer in [2, 400]"),
    ("a landscape grid of 1e5", ["landscape", "--run", "RUN", "--grid", "100000"], None, "an integer in [2, 400]"),
    ("eval 5000 seeds", ["eval", "--run", "RUN", "--eval-seeds", "5000"], None, "an integer in [1, 1000]"),
    ("eval a million envs", ["eval", "--run", "RUN", "--num-envs", "1000000"], None, "an integer in [1, 65536]"),
    (
        "sweep a seed past int32",
        ["sweep", *ANT, "--algos", "shac", "--epochs", "1", "--out", "o", "--seeds", "0", str(2**31)],
        None,
        "an integer in [0, 2147483647]",
    ),
    ("resume nothing", ["train", "--resume", "nowhere"], None, "not a run directory"),
    (
        "resume with other settings",
        ["train", "--resume", "RUN", "--gamma", "0.5", "--algo", "sapo"],
        None,
        "drop --algo, --gamma",
    ),
    (
        "resume to fewer epochs",
        ["train", "--resume", "RUN", "--epochs", "1"],
        "planned_2",
        "fewer than the run's planned 2",
    ),
    ("resume a truncated config", ["train", "--resume", "RUN"], "truncate_config", "config.json is unreadable"),
    (
        "resume a config without keys",
        ["train", "--resume", "RUN"],
        "empty_config_object",
        "config.json: it has no 'task'",
    ),
    ("resume a garbage checkpoint", ["train", "--resume", "RUN"], "garbage_checkpoint", "checkpoint.pt is unreadable"),
    ("resume an empty checkpoint", ["train", "--resume", "RUN"], "empty_checkpoint", "checkpoint.pt is unreadable"),
    ("resume a corrupt metrics middle", ["train", "--resume", "RUN"], "corrupt_metrics_middle", "corrupt line 1"),
    ("eval nothing", ["eval", "--run", "nowhere"], None, "not a run directory"),
    ("eval without checkpoint", ["eval", "--run", "RUN"], "missing_checkpoint", "has no checkpoint.pt yet"),
    ("eval a truncated config", ["eval", "--run", "RUN"], "truncate_config", "config.json is unreadable"),
    ("eval zero seeds", ["eval", "--run", "RUN", "--eval-seeds", "0"], None, "an integer in [1, 1000]"),
    ("report nothing", ["report", "--runs", "nowhere", "--out", "r"], None, "not a run directory"),
    ("report into a directory", ["report", "--runs", "RUN", "--out", "RUN"], None, "is a directory"),
    ("gradcheck nan tolerance", ["gradcheck", *ANT, "--tolerance", "nan"], None, "positive finite"),
    ("gradcheck negative tolerance", ["gradcheck", *ANT, "--tolerance", "-1"], None, "positive finite"),
    ("throughput zero windows", ["throughput", *ANT, "--windows", "0"], None, "[1, 1000]"),
    ("throughput into a directory", ["throughput", *ANT, "--out", "RUN"], None, "is a directory"),
    (
        "grad-growth bogus constant",
        ["grad-growth", "--run", "RUN", "--variant", "bogus=1"],
        None,
        "unknown physics constant",
    ),
    ("grad-growth text value", ["grad-growth", "--run", "RUN", "--variant", "contact_kf=abc"], None, "contact_kf"),
    (
        "crosscheck unknown backend",
        ["crosscheck", "--task", "ant", "--backends", "newton", "bullet"],
        None,
        "unknown backend",
    ),
    ("crosscheck one backend", ["crosscheck", "--task", "ant", "--backends", "newton"], None, "two or more different"),
    (
        "crosscheck a backend twice",
        ["crosscheck", "--task", "ant", "--backends", "newton", "newton"],
        None,
        "two or more different",
    ),
    (
        "sweep into an empty path",
        ["sweep", *ANT, "--algos", "shac", "--epochs", "1", "--out", ""],
        None,
        "--out: expected a non-empty value",
    ),
    (
        "sweep into a file",
        ["sweep", *ANT, "--algos", "shac", "--epochs", "1", "--out", "FILE"],
        None,
        "is a file, not a directory",
    ),
    (
        "sweep with a bad algo",
        ["sweep", *ANT, "--algos", "shac", "ppo", "--epochs", "1", "--out", "o"],
        None,
        "unknown algorithm",
    ),
    (
        "sweep on ray at a malformed address",
        ["sweep", *ANT, "--algos", "shac", "--epochs", "1", "--out", "o", "--launcher", "ray", "--address", "x"],
        None,
        "expected HOST:PORT",
    ),
    (
        "bench on ray where no head answers",
        ["bench", "--profile", "smoke", "--launcher", "ray", "--address", "127.0.0.1:1"],
        None,
        "no Ray head answers",
    ),
    (
        "bench --address without ray",
        ["bench", "--profile", "smoke", "--address", "127.0.0.1:6379"],
        None,
        "for --launcher ray",
    ),
    ("bench unknown launcher", ["bench", "--profile", "smoke", "--launcher", "slurm"], None, "invalid choice"),
    ("bench on an unknown device", ["bench", "--profile", "smoke", "--device", "tpu"], None, "unknown device"),
    ("bench on a missing GPU", ["bench", "--profile", "smoke", "--device", "cuda"], "no_cuda", "no CUDA device"),
    (
        "sweep zero jobs",
        ["sweep", *ANT, "--algos", "shac", "--epochs", "1", "--out", "o", "--jobs", "0"],
        None,
        "[1, 1024]",
    ),
    ("solver-probe unknown task", ["solver-probe", "--task", "dog"], None, "unknown task"),
    ("solver-probe task without candidates", ["solver-probe", "--task", "pointmass"], None, "candidates for the tasks"),
    (
        "solver-probe zero steps",
        ["solver-probe", "--task", "go2", "--max-steps", "0"],
        None,
        "an integer in [1, 1000000]",
    ),
    (
        "grad-growth substeps variant as text",
        ["grad-growth", "--run", "RUN", "--variant", "substeps=x"],
        None,
        "substeps",
    ),
]


# run folders whose config.json and checkpoints disagree with each other or with this machine: every verb
# that loads a policy refuses them the same way (harness/run/folder.py), before it writes anything
RUN_VERBS = {
    "eval": ["eval", "--run", "RUN", "--eval-seeds", "1"],
    "resume": ["train", "--resume", "RUN", "--epochs", "2"],
    "landscape": ["landscape", "--run", "RUN", "--grid", "2"],
    "render": ["render", "--run", "RUN", "--max-steps", "2"],
    "grad-growth": ["grad-growth", "--run", "RUN", "--variant", "contact_ke=1e4"],
}
CLI_CASES += [  # a flag that takes one value, given twice: refused rather than the last one kept
    ("train given --resume twice", ["train", "--resume", "RUN", "--resume", "RUN"], None, "--resume given twice"),
    ("gradcheck given --backend twice", ["gradcheck", *ANT, "--backend", "newton"], None, "--backend given twice"),
    ("render given --compare twice", ["render", "--run", "RUN", "--compare", "--compare"], None, "given twice"),
    (
        "parity given --backends twice",
        ["parity", "--task", "ant", "--backends", "newton", "--backends", "x"],
        None,
        "--backends given twice",
    ),
]
CLI_CASES += [  # adapter options that cannot mean anything: refused when the adapter is built, before any write
    ("a NaN contact gap", ["gradcheck", *ANT, "--backend-option", "contact_gap=nan"], None, "contact_gap must be"),
    (
        "a negative contact gap",
        ["gradcheck", *ANT, "--backend-option", "contact_gap=-0.1"],
        None,
        "contact_gap must be",
    ),
    (
        "a fractional refresh interval",
        ["gradcheck", *ANT, "--backend-option", "mass_matrix_every=1.5"],
        None,
        "an integer",
    ),
    (
        "no contact rows on mujoco_warp",
        ["gradcheck", "--backend", "mujoco_warp", "--task", "ant", "--backend-option", "nconmax=0"],
        None,
        "nconmax must be",
    ),
]
if "pointmass" in backends.available():  # a plug-in named where it cannot serve: one line naming why
    CLI_CASES += [
        (
            "contact-jacobians on an engine without MuJoCo's model",
            [
                "contact-jacobians",
                "--backend",
                "pointmass",
                "--task",
                "pointmass",
                "--states",
                "4",
                "--policy-epochs",
                "0",
            ],
            None,
            "finds contacts with MuJoCo's model of the task",
        ),
        (
            "render on an engine that cannot run the task",
            ["render", "--run", "RUN", "--backend", "pointmass", "--max-steps", "2"],
            None,
            "pointmass cannot run ant",
        ),
        ("parity of a task without a floating base", ["parity", "--task", "pointmass"], None, "floating-base robots"),
        ("fd-schemes on a task MuJoCo-Warp cannot build", ["fd-schemes", "--task", "pointmass"], None, "cannot load"),
    ]
CLI_CASES += [  # engine settings and options that cannot serve, in one line
    ("render with an unknown MUJOCO_GL", ["render", "--run", "RUN", "--max-steps", "2"], "bad_gl", "MUJOCO_GL='bogus'"),
    (
        "contact-jacobians with an option the adapter lacks",
        ["contact-jacobians", *ANT, "--backend-option", "bogus=1", "--states", "2", "--policy-epochs", "0"],
        None,
        "has no option 'bogus'",
    ),
]
CLI_CASES += [  # an output in the way, found before the work rather than after it
    ("bench-run on a job file missing keys", ["bench-run", "RUN"], "partial_job", "it has no seed, device, epochs"),
    (
        "render where its video's name is a folder",
        ["render", "--run", "RUN", "--max-steps", "2"],
        "video_folder",
        "is a directory",
    ),
]
CLI_CASES += [  # the bound audit: every count a flag, a hyperparameter or a spec takes has an upper bound
    ("a million timed windows", ["throughput", *ANT, "--windows", "1000000"], None, "[1, 1000]"),
    ("a tolerance above 1", ["gradcheck", *ANT, "--tolerance", "5"], None, "(0, 1]"),
    ("a billion settle steps", ["gradcheck", *ANT, "--with-contact", "--settle", "1000000000"], None, "[0, 1000000]"),
    ("a billion worlds timed", ["throughput", *ANT, "--grad-cost-only", "1000000000"], None, "[1, 1048576]"),
    ("a scaling budget of a century", ["scaling", *ANT, "--max-seconds", "3e9"], None, "(0, 604800]"),
    ("a billion frames", ["render", "--run", "RUN", "--frames", "1000000000"], None, "[1, 1000]"),
    ("a million jobs at once", ["bench", "--profile", "smoke", "--jobs", "1000000"], None, "[1, 1024]"),
    ("a billion critic passes", [*TRAIN, "--critic-iterations", "1000000000", "--out", "new_run"], None, "[1, 1000]"),
    ("a hidden layer of a million", [*TRAIN, "--actor-hidden", "1000000", "--out", "new_run"], None, "[1, 8192]"),
    (
        "more critic minibatches than samples",
        [*TRAIN, "--critic-minibatches", "17", "--out", "new_run"],
        None,
        "num_envs x horizon = 16",
    ),
    ("more lambda batches than envs", [*TRAIN, "--lambda-batches", "5", "--out", "new_run"], None, "num_envs = 4"),
    ("a spec's check asking a million windows", ["bench", "--spec", "FILE", "--dry-run"], "bad_spec_args", "[1, 1000]"),
    (
        "a spec's check on a preset the task lacks",
        ["bench", "--spec", "FILE", "--dry-run"],
        "bad_spec_preset",
        "task 'ant' has no physics preset 'nope'",
    ),
    (
        "a spec's check on a preset for a plug-in task",
        ["bench", "--spec", "FILE", "--dry-run"],
        "plugin_spec_preset",
        "task 'pointmass' has no physics presets",
    ),
]
DELETE = object()  # a config.json field removed, as a version that did not write it left it
FOLDER_DAMAGES = [  # (what, config.json fields changed (dotted: nested), what the refusal says)
    ("fractional seed", {"seed": 1.5}, "seed is 1.5, not an integer"),
    ("text seed", {"seed": "abc"}, "seed is 'abc'"),
    ("seed past int32", {"seed": 2**40}, "not an integer in [0, 2147483647]"),
    ("another seed than the checkpoint's", {"seed": 5}, "written for seed 0, config.json says 5"),
    ("zero epochs", {"epochs": 0}, "epochs is 0"),
    ("a device this machine lacks", {"device": "cuda"}, "no CUDA device"),
    ("an unknown device", {"device": "tpu"}, "device 'tpu'"),
    ("an engine not installed", {"backend": "bullet"}, "unknown backend 'bullet'"),
    ("another task without the preset", {"task": "go2"}, "has no physics preset 'bench'"),
    ("another task", {"task": "go2", "physics_record.preset": "project"}, "written for task 'ant'"),
    ("more envs than the checkpoint's", {"algo.num_envs": 8}, "written for num_envs 4"),
    ("another horizon", {"algo.horizon": 8}, "written for horizon 4"),
    ("another algorithm", {"algo.algo": "sapo"}, "written for algo 'shac'"),
    ("other network sizes", {"algo.actor_hidden": [64, 64]}, "networks are not the ones"),
    ("an unknown engine option", {"backend_options": {"bogus": 1}}, "has no option 'bogus'"),
    ("an invalid hyperparameter", {"algo.gamma": 2.0}, "hyperparameters are invalid"),
    ("no task", {"task": None}, "task is None"),
    ("anonymous checkpoints, another task", {"task": "go2", "physics_record.preset": "project", "_anon": 1}, "(12,)"),
    ("anonymous checkpoints, more envs", {"algo.num_envs": 8, "_anon": 1}, "env state has 4 envs"),
    # written by another version: refused where today's defaults would fill what the run never had
    ("a hyperparameter it lacks", {"algo.critic_iterations": DELETE}, "has no hyperparameter critic_iterations"),
    ("a physics constant it lacks", {"physics.contact_ke": DELETE}, "has no physics constant contact_ke"),
    ("a physics constant unknown here", {"physics.bogus": 1.0}, "physics constant(s) bogus this version does not"),
    ("no physics preset recorded", {"preset": DELETE}, "records no physics preset"),
]
LONG = "n" * 300  # longer than any common file system's name limit (255 bytes)
DEEP = "/".join(["d" * 200] * 25)  # a path longer than PATH_MAX (4096)
CLI_CASES += [  # paths refused before any work, whatever the verb
    ("train under a name too long", [*TRAIN, "--out", LONG], None, "is 300 bytes; the file system takes"),
    ("train under a path too long", [*TRAIN, "--out", DEEP], None, "the path is"),
    ("train below a file", [*TRAIN, "--out", "FILE/run"], None, "is a file, not a directory"),
    ("eval into a name too long", ["eval", "--run", "RUN", "--out", LONG + ".json"], None, "is 305 bytes"),
    ("report into a name too long", ["report", "--runs", "RUN", "--out", LONG], None, "is 300 bytes"),
    ("gradcheck into a name too long", ["gradcheck", *ANT, "--out", LONG + ".json"], None, "is 305 bytes"),
    ("solver-probe into a name too long", ["solver-probe", "--task", "ant", "--out", LONG], None, "is 300 bytes"),
    ("solver-probe below a file", ["solver-probe", "--task", "ant", "--out", "FILE/p.json"], None, "is a file"),
    ("sweep under a name too long", ["sweep", *ANT, "--algos", "shac", "--epochs", "1", "--out", LONG], None, "bytes"),
    ("bench into a store below a file", ["bench", "--profile", "smoke", "--store", "FILE"], None, "is a file"),
    ("bench into a store too deep", ["bench", "--profile", "smoke", "--store", DEEP], None, "the path is"),
]
CLI_CASES += [
    (f"{verb}: {what}", args, fields, needle)
    for what, fields, needle in FOLDER_DAMAGES
    for verb, args in RUN_VERBS.items()
]


def _edit_config(run: Path, fields: dict) -> None:
    """Set config.json's (dotted) ``fields``; ``_anon`` strips the run each checkpoint records, as in
    checkpoints written before they recorded it."""
    import json

    config = json.loads((run / "config.json").read_text())
    for dotted, value in fields.items():
        if dotted == "_anon":
            for name in ("checkpoint.pt", "checkpoint_init.pt"):
                payload = torch.load(run / name, weights_only=False)
                payload.pop("run")
                torch.save(payload, run / name)
            continue
        *parents, key = dotted.split(".")
        node = config
        for parent in parents:
            node = node[parent]
        if value is DELETE:
            del node[key]
        else:
            node[key] = value
    (run / "config.json").write_text(json.dumps(config))


def _damage(run: Path, how: str | dict | None, monkeypatch) -> None:
    if isinstance(how, dict):
        _edit_config(run, how)
        monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    elif how == "truncate_config":
        _truncate(run / "config.json")
    elif how == "empty_config_object":
        (run / "config.json").write_text("{}")
    elif how == "garbage_checkpoint":
        (run / "checkpoint.pt").write_bytes(b"not a checkpoint at all")
    elif how == "empty_checkpoint":
        (run / "checkpoint.pt").write_bytes(b"")
    elif how == "corrupt_metrics_middle":
        text = (run / "metrics.jsonl").read_text()
        (run / "metrics.jsonl").write_text("{torn\n" + text)
    elif how == "missing_checkpoint":
        (run / "checkpoint.pt").unlink()
    elif how == "planned_2":
        import json

        config = json.loads((run / "config.json").read_text())
        config["epochs"] = 2
        (run / "config.json").write_text(json.dumps(config))
    elif how == "partial_job":
        (run / "job.json").write_text('{"task": "ant", "backend": "newton"}')
    elif how == "bad_gl":
        monkeypatch.setenv("MUJOCO_GL", "bogus")
    elif how == "video_folder":
        (run / "render_newton.mp4").mkdir()
    elif how == "bad_spec_args":
        spec = '[suite]\nname = "s"\n[[check]]\nkind = "throughput"\nbackends = ["newton"]\ntasks = ["ant"]\n'
        (run.parent / "file").write_text(spec + 'args = ["--windows", "1000000"]\n')
    elif how in ("bad_spec_preset", "plugin_spec_preset"):
        name = "ant" if how == "bad_spec_preset" else "pointmass"
        engine = "newton" if how == "bad_spec_preset" else "pointmass"
        spec = f'[suite]\nname = "s"\n[[check]]\nkind = "gradcheck"\nbackends = ["{engine}"]\ntasks = ["{name}"]\n'
        (run.parent / "file").write_text(spec + 'args = ["--preset", "nope"]\n')
    elif how == "no_cuda":
        monkeypatch.setattr(torch.cuda, "is_available", lambda: False)


@pytest.mark.parametrize("case, args, damage, needle", CLI_CASES, ids=[c[0] for c in CLI_CASES])
def test_bad_cli_input(case, args, damage, needle, template, tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    shutil.copytree(template, run)
    (tmp_path / "file").write_text("not a directory")
    _damage(run, damage, monkeypatch)
    monkeypatch.chdir(tmp_path)
    before = _snapshot(tmp_path)
    args = [a.replace("RUN", str(run)).replace("FILE", str(tmp_path / "file")) for a in args]
    assert main(args) == 2, case
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    assert needle in err, (needle, err)
    assert _snapshot(tmp_path) == before, "a refused command wrote or changed a file"


def test_checkpoints_record_their_run_and_a_matching_folder_opens(template):
    from harness.run.folder import open_run

    rng = torch.get_rng_state()
    config = open_run(template, ("checkpoint.pt", "checkpoint_init.pt"))
    assert torch.equal(torch.get_rng_state(), rng)  # checking draws no random numbers of the caller's
    for name in ("checkpoint.pt", "checkpoint_init.pt"):
        recorded = torch.load(template / name, weights_only=False)["run"]
        assert recorded == {"task": "ant", "backend": "newton", "seed": 0, "algo": "shac", "num_envs": 4, "horizon": 4}
    assert config["algo_config"].num_envs == 4


def test_resuming_an_older_config_says_what_it_read_under_todays_names(template, tmp_path, capsys):
    """An older config.json whose meaning carries over (a renamed physics constant, a hyperparameter
    that was never read) is upgraded explicitly: the resume names each change before it continues."""
    import json

    run = tmp_path / "run"
    shutil.copytree(template, run)
    config = json.loads((run / "config.json").read_text())
    config["physics"]["pd_ke"] = config["physics"].pop("pd_kp")
    config["algo"]["extra"] = {}
    (run / "config.json").write_text(json.dumps(config))
    assert main(["train", "--resume", str(run), "--epochs", "3"]) == 0
    out = capsys.readouterr().out
    assert "written by an older version: physics constant pd_ke read as pd_kp (renamed)" in out, out
    assert "hyperparameter 'extra' dropped (never read)" in out, out


def test_the_corpus_is_at_least_forty_cases():
    assert len(CLI_CASES) + len(API_CASES) >= 40


def test_a_torn_last_metrics_line_is_dropped_by_resume_and_report(template, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(template, run)
    with (run / "metrics.jsonl").open("a") as fh:
        fh.write('{"epoch": 1, "env_st')  # a kill in the middle of a row
    assert main(["report", "--runs", str(run), "--out", str(tmp_path / "r"), "--no-plot"]) == 0
    assert main(["train", "--resume", str(run), "--epochs", "2"]) == 0
    rows = (run / "metrics.jsonl").read_text().splitlines()
    assert len(rows) == 2 and all(row.startswith('{"epoch": ') for row in rows)


def _sim(**kw):
    return make("newton", make_task("ant"), **{"num_envs": 2, **kw})


API_CASES = [
    ("zero substeps", lambda: PhysicsSpec(substeps=0), ValueError, "substeps must be an integer >= 1"),
    ("negative substeps", lambda: PhysicsSpec(substeps=-4), ValueError, "substeps"),
    ("fractional substeps", lambda: PhysicsSpec(substeps=2.5), ValueError, "substeps"),
    ("zero dt", lambda: PhysicsSpec(frame_dt=0.0), ValueError, "frame_dt must be a finite number > 0"),
    ("negative dt", lambda: PhysicsSpec(frame_dt=-0.01), ValueError, "frame_dt"),
    ("negative stiffness", lambda: PhysicsSpec(contact_ke=-1.0), ValueError, "contact_ke"),
    ("non-integer num_envs", lambda: _sim(num_envs=2.5), ValueError, "num_envs must be an integer >= 1"),
    ("zero num_envs", lambda: _sim(num_envs=0), ValueError, "num_envs"),
    ("zero graph depth", lambda: _sim(max_graph_steps=0), ValueError, "max_graph_steps"),
    ("a bool time step", lambda: PhysicsSpec(frame_dt=True), ValueError, "frame_dt must be a finite number > 0"),
    ("a string ground plane", lambda: PhysicsSpec(ground_plane="no"), ValueError, "ground_plane must be True or False"),
    (
        "torque limits for another robot's joints",
        lambda: make_task("ant", physics=PhysicsSpec(torque_limits=(1.0,) * 12)),
        ValueError,
        "has 12 limits; task 'ant' has 8 joints",
    ),
    ("an actor with no inputs", lambda: _actor(obs_dim=0), ValueError, "in_dim must be an integer >= 1"),
    ("an empty hidden layer", lambda: _actor(hidden_sizes=(64, 0)), ValueError, "a hidden size must be"),
    ("a task observing fewer columns", lambda: _short_sighted_env(), ValueError, "declares obs_dim 37"),
    (
        "a preset for a plug-in task that has none",
        lambda: make_task("pointmass", preset="rewarped"),
        ValueError,
        "task 'pointmass' has no physics presets",
    ),
]


def _actor(obs_dim=4, hidden_sizes=(64,)):
    from algorithms.networks import GaussianActor

    return GaussianActor(obs_dim, 2, hidden_sizes)


def _short_sighted_env():
    """A TaskEnv over a task whose observe() returns one column fewer than its obs_dim."""
    from tasks.env import TaskEnv

    task = make_task("ant")
    observe = task.observe
    task.observe = lambda state, prev: observe(state, prev)[:, :-1]
    return TaskEnv(task, make("newton", task, num_envs=2))


def _state_cases(sim):
    q, qd = sim.task.sample_initial_state(2, torch.Generator().manual_seed(0))
    zero = q.clone()
    zero[1, 3:7] = 0.0
    nan = qd.clone()
    nan[1, 0] = float("nan")

    def narrow(state):
        return dataclasses.replace(state, engine=state.engine[:, :-1])

    return [
        ("joint_q of the wrong width", lambda: sim.state_from_generalized(q[:, :5], qd), "joint_q must have shape"),
        ("joint_qd of the wrong rows", lambda: sim.state_from_generalized(q, qd[:1]), "joint_qd must have shape"),
        ("integer joint_q", lambda: sim.state_from_generalized(q.long(), qd), "floating-point"),
        ("zero quaternion", lambda: sim.state_from_generalized(zero, qd), "zero length in env(s) [1]"),
        ("state of the wrong rows", lambda: setattr(sim, "state", sim.state.map(lambda t: t[:1])), "rows for 2 envs"),
        ("NaN joint velocities", lambda: sim.state_from_generalized(q, nan), "NaN or inf in env(s) [1]"),
        ("a state of another width", lambda: setattr(sim, "state", narrow(sim.state)), "per-env shape"),
    ]


@pytest.mark.parametrize("case, build, exc, needle", API_CASES, ids=[c[0] for c in API_CASES])
def test_bad_api_input_raises_a_typed_one_line_error(case, build, exc, needle):
    with pytest.raises(exc) as info:
        build()
    assert needle in str(info.value) and "\n" not in str(info.value)


def test_bad_states_and_actions_are_refused_before_the_engine():
    sim = _sim()
    for case, build, needle in _state_cases(sim):
        with pytest.raises(InvalidStateError) as info:
            build()
        assert needle in str(info.value) and "\n" not in str(info.value), case
    with pytest.raises(InvalidActionError):
        sim.step(torch.full((2, 8), float("nan")))
    with pytest.raises(InvalidActionError):
        sim.step(torch.zeros(2, 8, dtype=torch.long))
