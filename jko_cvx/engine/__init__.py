"""The study engine: the time loop (step policies from :mod:`jko_cvx.stepping`), trackers, verdicts, run directories."""
