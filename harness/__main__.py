"""``python -m harness``: the command line, with signals handled from the first line on.

Until a verb takes over SIGINT/SIGTERM (a training loop, to finish its epoch and checkpoint; ``bench-run``,
to release its run's claim), a signal stops the process with one line and exit code 128 + signal. It
stops by an exception raised where the program is, so every writer's cleanup runs on the way out: a
temporary file is removed and a report's staged set discarded, while every file already in place was
replaced whole.

A job of a local suite also watches the suite (``harness/suite/launchers.py``): when the suite's end of
the pipe it was given closes, the suite has died without passing anything on, and the job sends itself
one SIGINT, as the suite's Ctrl-C would have.
"""

import os
import signal
import sys
import threading

from harness import SUITE_LIFELINE


class _Stopped(BaseException):
    """A signal arrived: unwinds past every ``except Exception`` to the line below, through the finally
    blocks and context managers that clean up after the writers."""


def _stop_now(signum, frame):
    raise _Stopped(signum)


def _stop_when_the_suite_dies(lifeline: int) -> None:
    """Block until the suite's end of ``lifeline`` closes (it writes nothing), then ask this process to stop."""
    try:
        while os.read(lifeline, 1):
            pass
    except OSError:  # not a pipe this process can read: no lifeline to watch
        return
    os.kill(os.getpid(), signal.SIGINT)


for _signum in (signal.SIGINT, signal.SIGTERM):
    signal.signal(_signum, _stop_now)
_lifeline = os.environ.pop(SUITE_LIFELINE, "")  # popped: nothing this job starts inherits it
if _lifeline.isdigit():
    threading.Thread(target=_stop_when_the_suite_dies, args=(int(_lifeline),), daemon=True).start()

try:
    from harness.cli import main  # after the handlers: imports take seconds

    _code = main()
    sys.stdout.flush()
except _Stopped as stop:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the line below is the last word
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    sys.stderr.write(f"stopped: {signal.Signals(stop.args[0]).name}\n")
    sys.stderr.flush()
    sys.stdout.flush()
    os._exit(128 + stop.args[0])  # the cleanup ran while unwinding; no thread left behind may hold the exit
except BrokenPipeError:
    # the reader left (`python -m harness list | head`): end quietly, as a pipeline's writer does, with
    # stdout pointed at /dev/null so that the interpreter's own final flush cannot fail again
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    _code = 128 + signal.SIGPIPE
raise SystemExit(_code)
