"""``python -m harness peer``: a peer simulator's throughput, measured by its own script in its own environment.

Rewarped 1.3.3, the paper's simulator, pins Warp 1.3.3, which cannot share this project's environment
(Warp 1.19), so its throughput script (``benchmarks/peers/rewarped_throughput.py``, timed the way
``harness throughput`` times an adapter) runs under another interpreter: ``--python``, or the one
``DIFFSIM_REWARPED_PYTHON`` names (set-up: ``benchmarks/peers/README.md``). This verb runs it, then
writes its result with the harness's provenance (command, commit, machine) beside the peer's own
package versions and command. The script ships with the repository, not the package: run from a checkout.
"""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
from pathlib import Path

#: peer name -> (its script under benchmarks/peers/, the variable naming its interpreter)
PEERS = {"rewarped": ("rewarped_throughput.py", "DIFFSIM_REWARPED_PYTHON")}
#: the tasks each peer has, by this harness's task names
PEER_TASKS = {"rewarped": ("ant", "soft_jumper")}


class PeerUnavailable(ValueError):
    """The peer's script or interpreter is not here (one line: what to set up)."""


def peer_script(peer: str) -> Path:
    """The peer's script: in the checkout this module belongs to, else under the working directory."""
    name = Path("benchmarks") / "peers" / PEERS[peer][0]
    for root in (Path(__file__).resolve().parents[2], Path.cwd()):
        if (root / name).is_file():
            return root / name
    raise PeerUnavailable(f"{name} is not here: run `harness peer` from a checkout of the repository")


def peer_python(peer: str, python: str | None) -> str:
    """The interpreter of the peer's own environment: ``python``, else its variable's value."""
    variable = PEERS[peer][1]
    python = python or os.environ.get(variable)
    if not python:
        raise PeerUnavailable(
            f"set {variable} (or --python) to the interpreter of an environment with {peer} installed "
            "(benchmarks/peers/README.md)"
        )
    if not (Path(python).is_file() and os.access(python, os.X_OK)):
        raise PeerUnavailable(f"{python}: not an executable interpreter")
    return python


def run_peer(peer: str, task: str, args: list[str], python: str | None = None) -> dict:
    """The peer script's result for ``task`` (``args``: its other words, e.g. ``--num-envs 64``), with
    its command and package versions under ``peer_command`` and ``peer_packages``."""
    script, interpreter = peer_script(peer), peer_python(peer, python)
    with tempfile.TemporaryDirectory() as scratch:
        out = Path(scratch) / "peer.json"
        env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
        done = subprocess.run([interpreter, str(script), "--env", task, *args, "--out", str(out)], env=env)
        if done.returncode != 0 or not out.is_file():
            raise RuntimeError(f"{peer}'s script exited with {done.returncode} (its output is above)")
        result = json.loads(out.read_text())
    result["peer"] = peer
    result["task"] = task
    result["peer_command"] = result.pop("command", None)
    result["peer_packages"] = result.pop("packages", None)
    return result


# -- the verb and its line in the suite's checks table ---------------------------------------------


def verb(args) -> int:
    """``python -m harness peer``: the peer's own script in its own environment, its result written."""
    from harness.inputs import BadInput, check_output
    from harness.results import write_check

    if args.peer not in PEERS:
        raise BadInput(f"unknown peer {args.peer!r}; choose from: {', '.join(PEERS)}")
    if args.task not in PEER_TASKS[args.peer]:
        raise BadInput(f"{args.peer} has the tasks {', '.join(PEER_TASKS[args.peer])}, not {args.task!r}")
    check_output(args.out)
    words = ["--num-envs", str(args.num_envs), "--horizon", str(args.horizon), "--windows", str(args.windows)]
    try:
        result = run_peer(args.peer, args.task, words + list(args.peer_arg), python=args.python)
    except PeerUnavailable as exc:
        raise BadInput(str(exc)) from None
    print(f"wrote {write_check(args.out, 'peer', result)}")
    return 0


def summary(result: dict, kind: str) -> str:
    from harness.formatting import fmt

    return (
        f"{result.get('peer')}: {fmt(result.get('forward_steps_per_s'))} env-steps/s forward, "
        f"{fmt(result.get('forward_backward_steps_per_s'))} with gradients"
    )
