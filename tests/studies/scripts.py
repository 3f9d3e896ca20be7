"""Load a script of ``studies/`` (not a package) as a module, for the tests that run its ``main``."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

STUDIES = Path(__file__).resolve().parents[2] / "studies"


def load_study_script(relative: str) -> ModuleType:
    """The module of ``studies/<relative>`` (e.g. ``"bench_collision.py"``, ``"examples/verify_sqp.py"``), executed."""
    path = STUDIES / relative
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
