"""``python -m harness solver-probe``: run the Newton solver probe and write its result with provenance.

The probe itself (engine code) lives in :mod:`backends.newton.solver_probe`; this verb only feeds it
the task's asset and physics constants and writes the result file.
"""

from __future__ import annotations

import json

from harness.results import provenance, write_json


def run_probe(num_envs: int = 64, out: str | None = None, command: str | None = None) -> list[dict]:
    from backends.newton.solver_probe import probe_all
    from tasks import make_task

    ant = make_task("ant")
    results = []
    for result in probe_all(str(ant.asset_path), ant.physics, num_envs=num_envs):
        print(json.dumps(result), flush=True)
        results.append(result)
    if out:
        print(f"wrote {write_json(out, {'runs': results, 'provenance': provenance(command)})}")
    return results
