"""The study engine: the time loop, step policies, trackers, verdicts and run directories."""
