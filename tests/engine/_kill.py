"""Run ``jko-cvx`` in a child process and signal it once a file of its run exists (kill/resume tests)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path


def signal_cli_when(argv: list[str], path: Path, signum: int, settle: float = 0.0, timeout: float = 120.0) -> None:
    """Start ``python -m jko_cvx.cli *argv``, wait until ``path`` exists (or the child ends, or ``timeout``
    seconds pass), wait ``settle`` seconds more, send ``signum`` and wait for the child to end."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "jko_cvx.cli", *argv],
        env=dict(os.environ, PYTHONUNBUFFERED="1"),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + timeout
    while not path.exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.02)
    time.sleep(settle)
    proc.send_signal(signum)
    proc.wait()
