"""README's headline tables, made from the result files they cite so that they cannot drift from them.

Each block sits in README between ``<!-- results:NAME -->`` and ``<!-- /results:NAME -->`` and is the
output of one function over the committed tables (:data:`BLOCKS`). ``python -m harness readme`` writes
every block anew; ``--check`` only compares and names the blocks that differ, which a test runs on the
repository's README, so a result re-made without its README block fails the tests.
"""

from __future__ import annotations

import csv
import json
import math
import re
from collections.abc import Callable
from pathlib import Path

from harness.formatting import markdown_table
from harness.results import RunError, atomic_write_text

PROTOCOL = Path("results/bench/protocol")
ALGORITHM_NAMES = {
    "shac": "SHAC",
    "shac-tdfixed": "SHAC-TDFixed",
    "shac-tdadpt": "SHAC-TDAdpt",
    "sapo": "SAPO",
    "sapo-tdfixed": "SAPO-TDFixed",
    "sapo-tdadpt": "SAPO-TDAdpt",
}


def _rows(path: Path) -> list[dict]:
    try:
        with open(path, newline="") as handle:
            return list(csv.DictReader(handle))
    except OSError as exc:
        raise RunError(f"README's tables read {path}, which cannot be read ({exc.strerror})") from None


def _pct(value: str) -> str:
    number = float(value)
    return "unbounded" if not math.isfinite(number) else f"{100 * number:+.0f}%"


def _interval(row: dict) -> str:
    low, high = row["change_ci_low"], row["change_ci_high"]
    if not low or not high:
        return "n/a"
    return f"[{_pct(low)}, {_pct(high)}]"


def _design(row: dict) -> str:
    if row["design"] == "continue":
        return f"continue to {row['seeds_wanted']} seeds"
    if row["design"] == "before first look":
        return f"to {row['seeds_wanted']} seeds, then the first look"
    return row["design"]


def _look_label(claim: dict) -> str:
    """Which look the claim's interval is read at (``look`` holds e.g. "5 pairs"); pairs that arrived
    after it wait for the next look and are named beside it."""
    if not claim["look"]:
        return f"{claim['pairs']} pairs, before the first look"
    at = int(claim["look"].split()[0])
    waiting = int(claim["pairs"]) - at
    return f"the {at}-pair look" + (f"; {claim['pairs']} pairs so far" if waiting > 0 else "")


def _paper_algorithms(rows: list[dict]) -> list[dict]:
    """The rows of the paper's six algorithms, in their order; an ablation's rows (``sapo-tdadpt (m_lambda
    0.5)``, a setting of Fig. 6) are not one of them and stay in the tables that list every run group."""
    order = list(ALGORITHM_NAMES)
    return sorted((r for r in rows if r["algo"] in ALGORITHM_NAMES), key=lambda r: order.index(r["algo"]))


def protocol_ant(root: Path) -> str:
    """The Ant protocol's final returns and each TD-lambda variant's claim against its base."""
    setting = {"task": "ant", "backend": "newton", "num_envs": "64", "horizon": "32", "epochs": "2000"}
    returns = [r for r in _rows(root / PROTOCOL / "returns.csv") if all(r[k] == v for k, v in setting.items())]
    claims = {
        r["algo"]: r
        for r in _rows(root / PROTOCOL / "returns_claims.csv")
        if r["metric"] == "return" and all(r[k] == v for k, v in setting.items())
    }
    header = ["algorithm (seeds)", "IQM (descriptive)", "vs its base: mean ratio - 1, seed-paired [interval]"]
    header += ["paper's claim: verdict", "design"]
    rows = []
    for row in _paper_algorithms(returns):
        claim = claims.get(row["algo"])
        cells = [f"{ALGORITHM_NAMES[row['algo']]} ({row['seeds']})", f"{float(row['iqm_final']):.0f}", "", "", ""]
        if claim is not None:
            level = f"{100 * float(claim['confidence']):g}%"
            look = _look_label(claim)
            cells[2] = f"{_pct(claim['measured_change'])} {_interval(claim)} ({level}, {look})"
            cells[3] = f"{_pct(claim['claimed_change'])}: {claim['verdict'].split(' (')[0]}"
            cells[4] = _design(claim)
        rows.append(cells)
    return "\n".join(markdown_table(header, rows))


def protocol_go2(root: Path) -> str:
    """The Go2 at the protocol's quarter budget: final return (IQM [95% bootstrap CI]) and forward
    velocity (mean [95% t CI]) per algorithm, with every seed's final (and untrained) values from its
    run's eval.json."""
    setting = {"task": "go2", "backend": "newton", "num_envs": "64", "horizon": "32", "epochs": "500"}
    pick = [(a, r) for a, r in _setting_rows(root / PROTOCOL / "returns.csv", setting)]
    velocity = dict(_setting_rows(root / PROTOCOL / "returns_locomotion.csv", setting))
    header = ["algorithm (seeds)", "final return IQM [95% CI]", "per seed (untrained)"]
    header += ["forward velocity m/s, all seeds' mean [95% t CI] (descriptive)", "per seed"]
    header += ["moves forward? (the look's mean [t CI])"]
    rows = []
    for algo, row in pick:
        evaluations = _seed_evaluations(root / PROTOCOL / "runs", "go2_newton", algo, "h32")
        finals = ", ".join(f"{e['final']['mean_return']:.0f}" for e in evaluations)
        untrained = ", ".join(f"{e['initial']['mean_return']:.0f}" for e in evaluations)
        speeds = ", ".join(f"{e['final']['mean_forward_velocity']:.2f}".replace("-0.00", "0.00") for e in evaluations)
        v = velocity[algo]
        cells = [
            f"{ALGORITHM_NAMES[algo]} ({row['seeds']})",
            f"{float(row['iqm_final']):.0f} [{float(row['iqm_ci_low']):.0f}, {float(row['iqm_ci_high']):.0f}]",
            f"{finals} ({untrained})",
            f"{float(v['final_velocity']):.2f} [{float(v['final_velocity_ci_low']):.2f}, "
            f"{float(v['final_velocity_ci_high']):.2f}]",
            speeds,
            _locomotion_look(v),
        ]
        rows.append(cells)
    return "\n".join(markdown_table(header, rows))


def _locomotion_look(row: dict) -> str:
    """The locomotion verdict at its look (docs/statistics.md): the verdict, the look, its mean and interval."""
    if not row["look"]:
        return f"{row['verdict']}"
    level = f"{100 * float(row['confidence']):g}%"
    interval = f"[{float(row['look_ci_low']):.2f}, {float(row['look_ci_high']):.2f}]"
    look = row["look"].replace(" seeds", "-seed")
    return f"{row['verdict']} ({look} look: {float(row['look_velocity']):.2f} {interval}, {level})"


def _setting_rows(path: Path, setting: dict) -> list[tuple[str, dict]]:
    """(algorithm, row) of a table's rows at one setting, in the algorithms' order."""
    rows = [r for r in _rows(path) if all(r[k] == v for k, v in setting.items())]
    return [(r["algo"], r) for r in _paper_algorithms(rows)]


def _seed_evaluations(runs: Path, prefix: str, algo: str, horizon: str) -> list[dict]:
    """The eval.json of every seed of one algorithm's runs, by seed."""
    found = {}
    for path in runs.glob(f"{prefix}_{algo}_{horizon}_s*_*/eval.json"):
        seed = int(path.parent.name.removeprefix(f"{prefix}_{algo}_{horizon}_s").split("_")[0])
        found[seed] = json.loads(path.read_text())
    return [found[s] for s in sorted(found)]


STANDARD = Path("results/bench/standard")
TASK_NAMES = {"ant": "Ant", "go2": "Go2", "soft_jumper": "SoftJumper"}


def standard_returns(root: Path) -> str:
    """The standard profile's final returns: per task, the one setting (N, h, epochs) where all six
    algorithms trained on Newton, IQM [95% bootstrap CI] (seeds)."""
    rows = [r for r in _rows(root / STANDARD / "returns.csv") if r["backend"] == "newton" and r["task"] in TASK_NAMES]
    table = []
    for task, name in TASK_NAMES.items():
        settings: dict[tuple, dict] = {}
        for r in rows:
            if r["task"] == task:
                settings.setdefault((r["num_envs"], r["horizon"], r["epochs"], r["env_steps"]), {})[r["algo"]] = r
        full = [key for key, algos in settings.items() if set(algos) == set(ALGORITHM_NAMES)]
        if len(full) != 1:
            raise RunError(
                f"{STANDARD / 'returns.csv'}: {task} has {len(full)} settings with all six algorithms, not one"
            )
        (envs, horizon, epochs, steps), algos = full[0], settings[full[0]]
        cells = [f"{name} ({envs} x {horizon} x {epochs} = {int(steps):,})"]
        for algo in ALGORITHM_NAMES:
            iqm, low, high = (float(algos[algo][k]) for k in ("iqm_final", "iqm_ci_low", "iqm_ci_high"))
            cells.append(f"{iqm:.0f} [{low:.0f}, {high:.0f}] ({algos[algo]['seeds']})")
        table.append(cells)
    return "\n".join(markdown_table(["task (N x h x epochs = env steps per run)", *ALGORITHM_NAMES], table))


def _sig(value: float) -> str:
    """Two significant digits below 100, a whole number above: how README writes a growth factor."""
    return f"{value:.0f}" if abs(value) >= 100 else f"{value:.2g}"


def grad_variance_growth(root: Path) -> str:
    """The standard profile's Fig. 7 (left): growth of each gradient statistic from the shortest to the
    longest h, per algorithm (ratio of the seeds' geometric means, 95% bootstrap CI)."""
    rows = [r for r in _rows(root / STANDARD / "grad_variance_vs_h_growth.csv") if r["task"] == "ant"]
    h_min = min(int(r["h_min"]) for r in rows)
    widest = {r["algo"]: r for r in rows if int(r["h_min"]) == h_min and r["backend"] == "newton"}

    def growth(row: dict, name: str) -> str:
        low, high = (float(row[f"{name}_growth_ci_{end}"]) for end in ("low", "high"))
        return f"{_sig(float(row[f'{name}_growth']))}x [{_sig(low)}, {_sig(high)}]"

    table = [
        [ALGORITHM_NAMES[a], growth(widest[a], "var"), growth(widest[a], "nsr")] for a in ALGORITHM_NAMES if a in widest
    ]
    return "\n".join(markdown_table(["", "raw variance", "noise-to-signal ratio"], table))


PARITY_TASKS = {"ant": "Ant", "go2": "Go2"}


def _default_preset_parity(root: Path, task: str) -> dict:
    """The parity check of ``task`` at its default preset (its command names no ``--preset``)."""
    import shlex

    from harness.words import physics_words

    found = []
    for path in sorted((root / STANDARD / "checks").glob(f"parity_{task}_*.json")):
        payload = json.loads(path.read_text())
        preset, _ = physics_words(shlex.split(payload["provenance"]["command"]))
        if preset is None:
            found.append(payload["result"])
    if len(found) != 1:
        raise RunError(f"{STANDARD / 'checks'}: {len(found)} parity checks of {task} at its default preset, not one")
    return found[0]


def parity(root: Path) -> str:
    """The standard profile's parity checks at each task's default preset, the engines side by side."""
    columns, cells = [], {k: [] for k in ("height", "joints", "episode", "law")}
    for task, name in PARITY_TASKS.items():
        result = _default_preset_parity(root, task)
        for i, backend in enumerate(result["backends"]):
            p = result["per_backend"][backend]
            columns.append(f"{name}: {ENGINE_NAMES.get(backend, backend)}")
            cells["height"].append(f"{p['settle']['height_m']:.4f}")
            cells["joints"].append("" if i else f"{result['gaps']['settle_joint_rad']:.4f}")
            cap = result["settings"]["max_steps"]
            mean = p["first_episode"]["mean"]
            cells["episode"].append(f"{cap} (none fell)" if mean >= cap else f"{mean:.1f}")
            law = max(
                abs(p["probe_contact"]["penetration_m"] / p["probe_contact"]["penalty_law_m"] - 1),
                abs(p["probe_limit"]["deflection_rad"] / p["probe_limit"]["penalty_law_rad"] - 1),
            )
            cells["law"].append(f"within {100 * law:.2g}%")
    labels = {
        "height": "trunk height after 2 s at rest (m)",
        "joints": "largest joint-angle gap after 2 s (rad)",
        "episode": f"random-policy first episode (mean steps, cap {cap})",
        "law": "probe penetration / limit deflection vs the penalty law",
    }
    return "\n".join(markdown_table(["", *columns], [[labels[k], *v] for k, v in cells.items()]))


ENGINE_NAMES = {"newton": "Newton", "mujoco_warp": "MuJoCo-Warp"}


#: block name -> the function that makes it from the repository root
BLOCKS: dict[str, Callable[[Path], str]] = {
    "protocol-ant": protocol_ant,
    "protocol-go2": protocol_go2,
    "standard-returns": standard_returns,
    "parity": parity,
    "grad-variance-growth": grad_variance_growth,
}


def _pattern(name: str) -> re.Pattern:
    return re.compile(rf"(<!-- results:{re.escape(name)} -->\n)(.*?)(\n<!-- /results:{re.escape(name)} -->)", re.S)


def render(text: str, root: Path) -> tuple[str, list[str]]:
    """``text`` with every block made anew, and the names of the blocks that changed. A block README
    lacks is refused: its markers name where it goes."""
    changed = []
    for name, make in BLOCKS.items():
        pattern = _pattern(name)
        if not pattern.search(text):
            raise RunError(f"README has no block {name!r} (between <!-- results:{name} --> and its closing marker)")
        fresh = make(root)
        current = pattern.search(text).group(2)
        if current != fresh:
            changed.append(name)
            text = pattern.sub(lambda m, fresh=fresh: m.group(1) + fresh + m.group(3), text)
    return text, changed


def update_readme(readme: Path, root: Path, check: bool = False) -> list[str]:
    """Make README's blocks from the results under ``root``; with ``check``, write nothing. Returns the
    names of the blocks that differed."""
    text = readme.read_text()
    fresh, changed = render(text, root)
    if changed and not check:
        atomic_write_text(readme, fresh)
    return changed
