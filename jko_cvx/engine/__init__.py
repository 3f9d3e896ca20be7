"""The study engine: the time loop, trackers, verdicts and run directories.

What a study imports from here: :func:`simulate` (the time loop of ``alg:MR_JKO_ver2`` and
``alg:SPMCSL-JKO``), :class:`Run` and :func:`load_run` (a run as data), :class:`Verdict` and
:class:`StopReason`, :class:`RunDirError` and :class:`RunInterrupted`.  The modules with a
leading underscore (the loop's state and files, the run directory, signal handling) are
internal.
"""

from jko_cvx.engine._interrupts import RunInterrupted
from jko_cvx.engine.errors import RunDirError
from jko_cvx.engine.loop import simulate
from jko_cvx.engine.run import Run, load_run
from jko_cvx.engine.verdict import StopReason, Verdict

__all__ = ["Run", "RunDirError", "RunInterrupted", "StopReason", "Verdict", "load_run", "simulate"]
