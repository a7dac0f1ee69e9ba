"""The harness's bounds on the numbers a user gives, one table read by the command line, the spec
schema and the run-folder check, so a flag, a spec key and a stored config refuse the same values.
Each bound says why it is where it is: a type's range, a memory or time figure, or what the paper uses.
"""

from __future__ import annotations

INT_MAX = 2**31 - 1  # seeds: torch.manual_seed and numpy generators take them; engines hash them as int32
MAX_ENVS = 65_536
MAX_GRID = 400
MAX_STEP_GAIN_STATES = 65_536
MAX_STRIDE = 1000
MAX_CONTACT_STATES = 4096  # contact-jacobians, fd-schemes: each state costs a float64 reference (about a second)
MAX_SEGMENT_STEPS = 10_000  # a compared or differentiated segment (gradcheck, crosscheck, parity); stored per step
MAX_SPAN = 100.0  # a landscape axis's half-width in the policy's parameter units (the paper's is 1)
MAX_EPOCHS = 10**6
MAX_HORIZON = 10_000
MAX_EVAL_SEEDS = 1000
MAX_STEPS = 10**6
