"""The bench suite's check kinds, each declared once: what it checks, how its jobs are addressed and
what a job of it costs. The spec schema's list of valid kinds and the planner's jobs both read it
(:func:`harness.suite.bench.plan`); each kind is also a verb of ``python -m harness`` of the same name.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class CheckKind:
    """How the suite runs one kind of check."""

    #: the kind's name: a ``[[check]]`` block's ``kind`` and the harness verb that runs it
    name: str
    #: rough seconds of one job on this project's 2-core CPU machine, for the ETA and the schedule
    seconds: float
    #: "backend": one job per backend (``--backend B --task T``); "backends": one job over all of a
    #: block's backends (``--backends ...``); "simulator": one job per named simulator, which the verb
    #: picks itself (``--task T`` only)
    targets: str = "backend"
    #: its result depends on how an adapter computes gradients, so its address carries their settings
    differentiates: bool = False
    #: its verb takes ``--device`` (the others run on the CPU)
    takes_device: bool = True
    #: the one backend it measures, when it measures one only
    only_backend: str | None = None


KINDS: dict[str, CheckKind] = {
    k.name: k
    for k in (
        CheckKind("gradcheck", 40.0, differentiates=True),
        CheckKind("throughput", 60.0, differentiates=True),
        CheckKind("crosscheck", 60.0, targets="backends", differentiates=True, takes_device=False),
        CheckKind("parity", 120.0, targets="backends", takes_device=False),
        CheckKind("contact-jacobians", 300.0, differentiates=True),
        CheckKind("grad-paths", 120.0, differentiates=True),
        CheckKind("scaling", 300.0, differentiates=True),
        CheckKind(
            "fd-schemes",
            150.0,
            targets="simulator",
            differentiates=True,
            takes_device=False,
            only_backend="mujoco_warp",
        ),
        CheckKind("solver-probe", 120.0, takes_device=False),
        CheckKind("peer", 120.0, targets="simulator", takes_device=False),
    )
}

#: every check kind's name, in the order the docs list them
CHECK_KINDS = tuple(KINDS)
