"""``python -m harness``: the command line, with signals handled from the first line on.

Until a verb takes over SIGINT/SIGTERM (a training loop, to finish its epoch and checkpoint; ``bench-run``,
to release its run's claim), a signal ends the process at once with one line and exit code 128 +
signal: nothing is half-written then, because every file this program writes outside an epoch is
replaced atomically.
"""

import os
import signal
import sys


def _stop_now(signum, frame):
    sys.stderr.write(f"stopped: {signal.Signals(signum).name}\n")
    sys.stderr.flush()
    os._exit(128 + signum)


for _signum in (signal.SIGINT, signal.SIGTERM):
    signal.signal(_signum, _stop_now)

from harness.cli import main  # noqa: E402  (after the handlers: imports take seconds)

try:
    _code = main()
    sys.stdout.flush()
except BrokenPipeError:
    # the reader left (`python -m harness list | head`): end quietly, as a pipeline's writer does, with
    # stdout pointed at /dev/null so that the interpreter's own final flush cannot fail again
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    _code = 128 + signal.SIGPIPE
raise SystemExit(_code)
