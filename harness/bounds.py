"""The harness's bounds on the numbers a user gives, one table read by the command line, the spec
schema and the run-folder check, so a flag, a spec key and a stored config refuse the same values.
Each bound says why it is where it is: a type's range, a memory or time figure, or what the paper uses.
"""

from __future__ import annotations

# the configuration's own bounds (AlgoConfig refuses the same values), re-exported for the flags
from algorithms.config import MAX_ENVS as MAX_ENVS
from algorithms.config import MAX_EPOCHS as MAX_EPOCHS
from algorithms.config import MAX_HORIZON as MAX_HORIZON

INT_MAX = 2**31 - 1  # seeds: torch.manual_seed and numpy generators take them; engines hash them as int32
MAX_GRID = 400
MAX_STEP_GAIN_STATES = 65_536
MAX_STRIDE = 1000
MAX_CONTACT_STATES = 4096  # contact-jacobians, fd-schemes: each state costs a float64 reference (about a second)
MAX_SEGMENT_STEPS = 10_000  # a compared or differentiated segment (gradcheck, crosscheck, parity); stored per step
MAX_SPAN = 100.0  # a landscape axis's half-width in the policy's parameter units (the paper's is 1)
MAX_EVAL_SEEDS = 1000
MAX_STEPS = 10**6
MAX_WINDOWS = 1000  # timed windows of a speed check: the best of them is kept, and 1000 is hours on a CPU
MAX_JOBS = 1024  # jobs at once: processes here, Ray tasks on a cluster
MAX_GPUS_PER_RUN = 64.0  # GPUs one run asks Ray for
MAX_TOLERANCE = 1.0  # a relative error: above 1 the gradients share nothing
MAX_WORLDS = 2**20  # worlds of one timed finite-difference step (a soft body's 3,109 per env at 256 envs is 0.8 M)
MAX_SECONDS = 7 * 24 * 3600.0  # a wall-clock budget of one measurement: a week
MAX_FRAMES = 1000  # frames of a filmstrip or video drawn from one episode
