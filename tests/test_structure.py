"""The layering, the shared vocabulary, the task registry, the rollout objective, packaging and the CLI docs."""

from __future__ import annotations

import ast
import dataclasses
import json
import math
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import torch

import simcore
from algorithms.config import AlgoConfig
from harness.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]


def _imports(path: Path) -> set[str]:
    """Top-level and dotted module names imported anywhere in ``path`` (TYPE_CHECKING blocks included)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def _modules(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


def test_tasks_never_import_backends_and_adapters_never_import_tasks_or_the_harness():
    for path in _modules("tasks"):
        bad = {m for m in _imports(path) if m.split(".")[0] in ("backends", "harness", "algorithms")}
        assert not bad, f"{path.relative_to(ROOT)} imports {bad}"
    for path in _modules("backends"):
        bad = {m for m in _imports(path) if m.split(".")[0] in ("tasks", "harness", "algorithms")}
        assert not bad, f"{path.relative_to(ROOT)} imports {bad}"
    for path in _modules("algorithms"):
        bad = {m for m in _imports(path) if m.split(".")[0] in ("backends", "harness", "newton", "warp", "mujoco")}
        assert not bad, f"{path.relative_to(ROOT)} imports {bad}"
    vocabulary = {m.split(".")[0] for m in _imports(ROOT / "simcore.py")}
    assert not vocabulary & {"tasks", "backends", "harness", "algorithms"}


def test_engines_are_imported_only_inside_their_adapter_packages():
    engines = {"newton", "warp", "mujoco", "mujoco_warp"}
    for package in ("tasks", "algorithms", "harness"):
        for path in _modules(package):
            bad = {m for m in _imports(path) if m.split(".")[0] in engines}
            assert not bad, f"{path.relative_to(ROOT)} imports {bad}"
    assert not {m.split(".")[0] for m in _imports(ROOT / "simcore.py")} & engines


def _harness_import_graph() -> dict[str, set[str]]:
    """Module -> the harness modules it imports anywhere (inside functions too: a lazy import still
    ties the two modules together), a package's ``__init__`` counted as the package."""
    paths = {}
    for path in _modules("harness"):
        parts = path.relative_to(ROOT).with_suffix("").parts
        paths[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    graph = {}
    for name, path in paths.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(up + ([node.module] if node.module else []))
                targets.add(base)
                targets.update(f"{base}.{alias.name}" for alias in node.names)
        graph[name] = {t for t in targets if t in paths and t != name}
    return graph


def test_the_harness_has_no_import_circle():
    """Every harness module can be read knowing only the modules below it: no chain of imports, lazy
    ones included, returns to where it started."""
    graph = _harness_import_graph()
    assert "harness.suite.bench" in graph["harness.suite.runner"]  # the graph sees real edges
    done: set[str] = set()

    def visit(name: str, path: list[str]) -> None:
        if name in path:
            cycle = path[path.index(name) :] + [name]
            pytest.fail("import circle: " + " -> ".join(cycle))
        if name in done:
            return
        for target in sorted(graph[name]):
            visit(target, path + [name])
        done.add(name)

    for name in sorted(graph):
        visit(name, [])


#: harness/'s wings, each importing only its own and those after it: the command line drives the suite,
#: the suite writes reports, a report sums up checks (each kind's summary) and runs, checks read runs,
#: and everything stands on the core modules (results, bounds, words, formatting, figures, envs, inputs,
#: progress, resources) at the package's top.
WINGS = ("cli", "suite", "report", "checks", "run", "core")
#: top-level modules that sit above every wing: the entry point and the two public APIs for other packages
ABOVE_THE_WINGS = {"harness.__main__", "harness.contract_suite", "harness.diffenv"}


def _wing(module: str) -> str:
    part = module.split(".")[1] if module.count(".") else "core"
    return part if part in WINGS else "core"


def test_the_harness_wings_import_only_downwards():
    """A wing never imports one above it, so a newcomer reads ``run/`` without ``suite/``, and ``checks/``
    without the command line."""
    graph = _harness_import_graph()
    assert {_wing(m) for m in graph} == set(WINGS)  # every wing is a package with modules in it
    upward = [
        f"{name} -> {target}"
        for name, targets in graph.items()
        if name not in ABOVE_THE_WINGS
        for target in targets
        if target not in ABOVE_THE_WINGS and WINGS.index(_wing(target)) < WINGS.index(_wing(name))
    ]
    assert not upward, "imports against the wings' order:\n" + "\n".join(sorted(upward))


def test_no_function_in_the_harness_or_the_adapters_is_over_100_lines():
    """A function a person can hold in their head: the harness's and the adapters' functions stay under
    101 lines, docstring and comments included."""
    long = []
    for package in ("harness", "backends"):
        for path in _modules(package):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    lines = node.end_lineno - node.lineno + 1
                    if lines > 100:
                        long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({lines} lines)")
    assert not long, "; ".join(long)


def test_the_pd_law_is_specified_once_in_the_physics_spec():
    spec = simcore.PhysicsSpec(pd_kp=30.0, pd_kd=0.5, torque_limits=(23.7, 45.43))
    target = torch.tensor([[1.0, 0.0], [0.01, 0.0]])
    q = torch.zeros(2, 2)
    qd = torch.tensor([[0.0, 4.0], [0.0, -1.0]])
    tau = spec.pd_torque(target, q, qd)
    torch.testing.assert_close(tau, torch.tensor([[23.7, -2.0], [0.3, 0.5]]))  # clipped at the hip limit
    with pytest.raises(ValueError, match="torque limits"):
        spec.pd_torque(torch.zeros(1, 3), torch.zeros(1, 3), torch.zeros(1, 3))


@pytest.mark.parametrize("bad", [{"substeps": 0}, {"substeps": -2}, {"substeps": 2.5}, {"frame_dt": 0.0}])
def test_physics_spec_refuses_a_frozen_or_backwards_simulation(bad):
    with pytest.raises(ValueError, match="PhysicsSpec"):
        simcore.PhysicsSpec(**bad)


def test_every_asset_kind_ships_in_the_wheel(tmp_path):
    """Package data covers MJCF, URDF, meshes and tet meshes, and the wheel records the commit it was
    built from (built from a copy of the tree, not in place)."""
    pytest.importorskip("setuptools")
    tree = tmp_path / "src"
    skip = (".git", ".tox", ".venv", "results", "build", "*.egg-info", "__pycache__", ".*_cache")  # not the package's
    shutil.copytree(ROOT, tree, ignore=shutil.ignore_patterns(*skip))
    kinds = {"probe.urdf": "<robot/>", "meshes/probe.obj": "v 0 0 0\n", "meshes/probe.stl": "solid\n"}
    kinds |= {"tetmesh/probe.msh": "$MeshFormat\n", "tetmesh/probe.npz": "", "probe.xml": "<mujoco/>"}
    for name, text in kinds.items():
        (tree / "tasks" / "assets" / name).parent.mkdir(parents=True, exist_ok=True)
        (tree / "tasks" / "assets" / name).write_text(text)
    # a checkout of its own: the wheel records its commit (setup.py), as provenance reads it once installed
    git = ["git", "-c", "user.email=probe@example.com", "-c", "user.name=probe"]
    subprocess.run([*git, "init", "-q"], cwd=tree, check=True)
    subprocess.run([*git, "commit", "-q", "--allow-empty", "-m", "probe"], cwd=tree, check=True)
    head = subprocess.run([*git, "rev-parse", "--short", "HEAD"], cwd=tree, capture_output=True, text=True).stdout
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path),
            str(tree),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    (wheel,) = tmp_path.glob("diffsim_bench-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for name in kinds:
        assert f"tasks/assets/{name}" in names, name
    assert "tasks/assets/ant.xml" in names and "simcore.py" in names
    assert zipfile.ZipFile(wheel).read("harness/_commit.txt").decode().strip() == head.strip()


def test_every_hyperparameter_flag_documents_itself():
    train = build_parser()._subparsers._group_actions[0].choices["train"]
    helps = {a.dest: a.help for a in train._actions}
    for f in dataclasses.fields(AlgoConfig):
        assert f.metadata.get("help"), f"AlgoConfig.{f.name} has no documentation"
        if f.name not in ("algo", "num_envs", "horizon"):  # shared flags, declared in harness.cli.FLAGS
            assert helps.get(f.name) == f.metadata["help"], f.name


def test_every_flag_is_declared_once():
    """No verb declares a flag of its own that FLAGS already defines (one type per flag; its help is
    FLAGS', or what the flag means in that verb: VERB_HELP's words, or its check kind's registry entry's)."""
    from harness.cli.parser import FLAGS, flag_help

    parser = build_parser()
    for verb, sub in parser._subparsers._group_actions[0].choices.items():
        for action in sub._actions:
            if action.dest in FLAGS:
                expected = flag_help(verb).get(action.dest, FLAGS[action.dest]["help"])
                assert action.help.startswith(expected), (verb, action.dest)


def test_algo_config_is_frozen_and_validated_once():
    cfg = AlgoConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.gamma = 0.5
    for bad in ({"actor_return": "gae"}, {"critic_iterations": 2.5}, {"betas": (1.5, 0.9)}, {"min_lr": -1.0}):
        with pytest.raises(ValueError):
            cfg.replace(**bad)
    assert AlgoConfig.from_dict(json.loads(json.dumps(cfg.as_dict()))) == cfg


_TRAIN = ["train", "--task", "ant", "--backend", "newton", "--algo", "shac", "--epochs", "1", "--out", "x"]


@pytest.mark.parametrize(
    "args, needle",
    [
        (["train", "--resume", "somewhere", "--gamma", "0.5"], "drop --gamma"),
        ([*_TRAIN, "--actor-return", "gae"], "invalid choice"),
        ([*_TRAIN, "--critic-iterations", "2.5"], "expected an integer"),
        ([*_TRAIN, "--target-critic-alpha", "1.5"], "target_critic_alpha must be in [0, 1]"),
        ([*_TRAIN, "--betas", "1.5", "0.9"], "betas must lie in [0, 1)"),
        ([*_TRAIN, "--min-lr", "-1"], "min_lr must be in"),
    ],
)
def test_bad_training_input_is_one_line(args, needle, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and needle in err, err
    assert not (tmp_path / "x").exists()


def test_warp_starts_quietly_on_a_cpu_machine_but_keeps_other_warnings():
    from backends._warp import NO_DRIVER_LINE, without_driver_line

    noisy = f"Warp CUDA warning: {NO_DRIVER_LINE}. GPU execution will not be available.\nWarp warning: real\n"
    assert without_driver_line(noisy) == "Warp warning: real\n"
    out = subprocess.run(
        [sys.executable, "-c", "import backends.newton, backends.mujoco_warp"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0 and NO_DRIVER_LINE not in out.stderr, out.stderr


def test_provenance_says_whether_the_checkout_had_uncommitted_changes(tmp_path):
    from harness.results import _git_dirty, provenance

    assert "git_dirty" in provenance("x")
    assert _git_dirty(tmp_path) is None  # not a checkout
    git = ["git", "-c", "user.email=probe@example.com", "-c", "user.name=probe"]
    subprocess.run([*git, "init", "-q"], cwd=tmp_path, check=True)
    (tmp_path / "tracked.txt").write_text("a\n")
    subprocess.run([*git, "add", "tracked.txt"], cwd=tmp_path, check=True)
    subprocess.run([*git, "commit", "-q", "-m", "probe"], cwd=tmp_path, check=True)
    assert _git_dirty(tmp_path) is False
    (tmp_path / "untracked.txt").write_text("b\n")
    assert _git_dirty(tmp_path) is False  # untracked files are not the code
    (tmp_path / "tracked.txt").write_text("changed\n")
    assert _git_dirty(tmp_path) is True


def test_provenance_says_which_machine_and_threads():
    from harness.results import provenance

    machine = provenance("x")["machine"]
    assert machine["cpu_model"] and machine["torch_num_threads"] >= 1
    assert {"OMP_NUM_THREADS", "torch_num_interop_threads", "cpu_count"} <= set(machine)


def test_every_check_kind_is_declared_once_and_the_cli_and_the_report_come_from_it():
    """A check kind's registry entry is its verb (flags, defaults, the function that runs it) and its line
    in the suite's checks table: the parser, the verbs and the report read it, nothing repeats it."""
    import importlib

    from harness.checks.kinds import BY_FILE_KIND, KINDS
    from harness.cli import VERBS
    from harness.results import CHECK_RESULT_KINDS

    choices = build_parser()._subparsers._group_actions[0].choices
    for name, kind in KINDS.items():
        module = importlib.import_module(f"harness.checks.{kind.module}")
        assert callable(module.verb) and callable(module.summary), name
        assert VERBS[name] == kind.run, name
        flags = {a.dest for a in choices[name]._actions}
        assert set(kind.flags) <= flags, name
        for dest, default in kind.defaults.items():
            assert choices[name].get_default(dest) == default, (name, dest)
        assert set(kind.required) <= set(kind.flags), name
    assert set(BY_FILE_KIND) <= set(CHECK_RESULT_KINDS)
    assert set(CHECK_RESULT_KINDS) - set(BY_FILE_KIND) == {"grad-growth"}  # not a suite check: no summary line


def test_every_markdown_table_goes_through_one_writer():
    """No module writes a Markdown table's separator row itself: :func:`harness.formatting.markdown_table`
    writes every table, so a cell's ``|`` never splits a row anywhere."""
    writer = ROOT / "harness" / "formatting.py"
    for package in ("harness", "backends", "benchmarks"):
        for path in _modules(package):
            if path != writer:
                assert "|---" not in path.read_text() and "---|" not in path.read_text(), path.relative_to(ROOT)


def test_every_number_a_flag_takes_is_bounded():
    """The bound audit: every numeric flag of every verb refuses, in its type, values past a bound of the
    machine, of time or of what it means (hyperparameters: AlgoConfig's own checks, tested below)."""
    unbounded = []
    hyperparameters = {f.name for f in dataclasses.fields(AlgoConfig)} - {"num_envs", "horizon"}
    for verb, sub in build_parser()._subparsers._group_actions[0].choices.items():
        for action in sub._actions:
            name = getattr(action.type, "__name__", "")
            if action.type is None or name in ("one_line", "parse_option", "boolean") or action.dest in hyperparameters:
                continue
            low, high = getattr(action.type, "bounds", (None, None))
            if high is None or not math.isfinite(high):
                unbounded.append(f"{verb} {action.option_strings[0]} ({name})")
    assert not unbounded, unbounded


@pytest.mark.parametrize(
    "change, needle",
    [
        ({"critic_iterations": 10**9}, "critic_iterations"),
        ({"lambda_iterations": 1e9}, "lambda_iterations"),
        ({"actor_hidden": (10**6,)}, "hidden widths"),
        ({"critic_hidden": (8,) * 64}, "hidden layers"),
        ({"num_critics": 1000}, "num_critics"),
        ({"num_envs": 10**6}, "num_envs"),
        ({"horizon": 10**6}, "horizon"),
        ({"max_epochs": 10**9}, "max_epochs"),
        ({"num_envs": 4, "horizon": 4, "critic_minibatches": 17}, "critic_minibatches"),
        ({"num_envs": 4, "lambda_batches": 5}, "lambda_batches"),
    ],
)
def test_every_count_of_the_configuration_has_an_upper_bound(change, needle):
    with pytest.raises(ValueError, match=needle):
        AlgoConfig().replace(**change)
