"""The suite: a spec read and checked (:mod:`.schema`), its jobs planned (:mod:`.bench`) and run
(:mod:`.runner`, here or on a cluster through :mod:`.launchers`), then its tables written by
:mod:`harness.report`. The suite talks to runs through :mod:`harness.run` and to checks through their
registry (:mod:`harness.checks.kinds`)."""
