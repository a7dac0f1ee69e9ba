"""The harness: command line, runs, suite, checks and reports (``python -m harness``)."""

# Named here, in a module every command imports anyway, so that ``__main__`` reads it before the CLI's imports
# and the suite's launcher writes the same name: the file descriptor of the pipe a local job watches, whose
# closing means the suite died.
SUITE_LIFELINE = "DIFFSIM_SUITE_LIFELINE"
