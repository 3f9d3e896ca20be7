"""SIGINT / SIGTERM during a run with a run directory: checkpoint the last accepted step and stop.

While :class:`InterruptGuard` is active, SIGINT and SIGTERM raise :class:`KeyboardInterrupt`
at once when the loop is solving a step (that step is discarded), but are held back while
it commits an accepted step and runs the trackers (``guard.deferred()``), so the state the
caller checkpoints is always that of a whole step.  The caller then raises
:class:`RunInterrupted`, which names the checkpoint; resuming from it reproduces the
uninterrupted run bit for bit (the checkpoint holds the whole state).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["InterruptGuard", "RunInterrupted"]

_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class RunInterrupted(KeyboardInterrupt):
    """A run stopped by SIGINT / SIGTERM after writing its checkpoint (``path``, ``step``, ``t``)."""

    def __init__(self, path: Path, step: int, t: float, signum: int) -> None:
        self.path, self.step, self.t, self.signum = path, step, t, signum
        name = signal.Signals(signum).name
        super().__init__(f"{name}: run in {path} stopped at step {step} (t = {t:g}); checkpoint written")


class _Signal(KeyboardInterrupt):
    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class InterruptGuard:
    """Installs the SIGINT / SIGTERM handlers (main thread only; elsewhere it does nothing)."""

    def __init__(self) -> None:
        self.pending: int | None = None
        self.deferring = False
        self.signum = signal.SIGINT
        self._previous: dict[int, object] = {}

    def _handler(self, signum: int, frame) -> None:
        self.signum = signum
        if self.deferring:
            self.pending = signum
            return
        raise _Signal(signum)

    def __enter__(self) -> InterruptGuard:
        if threading.current_thread() is threading.main_thread():
            for s in _SIGNALS:
                self._previous[s] = signal.signal(s, self._handler)
        return self

    def __exit__(self, *exc) -> None:
        for s, h in self._previous.items():
            signal.signal(s, h)
        self._previous.clear()

    @contextmanager
    def deferred(self) -> Iterator[None]:
        """Hold signals back for the block; one that arrived meanwhile is raised at its end."""
        self.deferring = True
        try:
            yield
        finally:
            self.deferring = False
            if self.pending is not None:
                signum, self.pending = self.pending, None
                raise _Signal(signum)

    def hold(self) -> None:
        """Ignore further signals from now on (while the checkpoint is written)."""
        self.deferring = True
