"""The environment a result was computed in: versions, git commit, processor, BLAS library and threads.

Numbers computed with another BLAS kernel, thread count or library version are not bit for
bit those of the shipped files (the order of floating-point sums changes); they agree within
stated tolerances.  Every result file therefore records the environment that produced it:
:func:`environment` is the record, :func:`environment_line` its one-line Markdown form, and
:func:`write_markdown` / :func:`record_csv` the writers the reproductions and benchmarks use
(a header line in each Markdown file; ``environment.json`` beside the CSV files, one entry per
file name).

Versions are read with :mod:`importlib.metadata`, not by importing the packages (importing
cvxpy takes about a second); the BLAS library is what :func:`threadpoolctl.threadpool_info`
finds loaded after numpy.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import json
import os
import platform
import subprocess
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

__all__ = [
    "ENVIRONMENT_FILE",
    "PACKAGES",
    "CodeChangedError",
    "code_fingerprint",
    "environment",
    "environment_line",
    "git_state",
    "installed_version",
    "library_versions",
    "package_files",
    "processor",
    "record_csv",
    "write_markdown",
]

PACKAGE_DIR = Path(__file__).resolve().parent
"""The ``jko_cvx`` package directory."""

PACKAGES = ("numpy", "scipy", "cvxpy", "clarabel", "threadpoolctl")
"""The distributions whose versions :func:`environment` records besides jko_cvx and Python."""

ENVIRONMENT_FILE = "environment.json"
"""The file beside CSV results that records, per file name, the environment that wrote it."""


PACKAGE_SUFFIXES = (".py", ".toml")
"""The files of the package its results depend on: modules and data (the shipped scenes)."""


def package_files() -> list[Path]:
    """The package's modules and data files (:data:`PACKAGE_SUFFIXES`), sorted: what :func:`code_fingerprint`
    covers (an editor's swap file or a ``.DS_Store`` beside them is no change of code)."""
    found = []
    for root, dirs, files in os.walk(PACKAGE_DIR):  # a tenth of rglob's time: the bytecode folders are not entered
        dirs[:] = [d for d in dirs if d != "__pycache__"]
        found += [p for name in files if (p := Path(root, name)).suffix in PACKAGE_SUFFIXES and p.is_file()]
    return sorted(found)


def _files_sha256() -> str:
    h = hashlib.sha256()
    for path in package_files():
        h.update(str(path.relative_to(PACKAGE_DIR)).encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


# the files as this process imported them: ``import jko_cvx`` imports this module before any other of its own
_AT_IMPORT = _files_sha256()


class CodeChangedError(RuntimeError):
    """The package's files changed on disk after this process imported them."""


def code_fingerprint(*, verify: bool = True) -> str:
    """SHA-256 over the relative paths and contents of the package's modules and data files (:func:`package_files`;
    hex), as they were when this process imported the package.

    The code and its data (a shipped scene file is what ``shipped_scene`` reads), where the version number is not
    enough: an edited checkout or an editable install keeps its version.  A study's cache and a run's checkpoint
    record it, and neither is reused under other code.

    Raises
    ------
    CodeChangedError
        The files on disk differ from those read at import (an edit since): the process runs the code it
        imported, while a module it imports from now on would be the edited one, so no single fingerprint
        describes what it computes.  Restart Python.  (Each call reads the files again, a few ms; ``verify=False``
        skips that and returns the fingerprint taken at import.)
    """
    if verify and (now := _files_sha256()) != _AT_IMPORT:
        raise CodeChangedError(
            f"jko_cvx's files in {PACKAGE_DIR} changed since this process imported them (SHA-256 "
            f"{_AT_IMPORT[:12]}... at import, {now[:12]}... now): a result computed now could not be labelled with "
            "the code that made it; restart Python to run the edited code"
        )
    return _AT_IMPORT


def installed_version(name: str) -> str:
    """The installed distribution's version, without importing it; ``"not installed"`` if absent."""
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


@functools.cache
def library_versions() -> str:
    """Python and the numerical libraries a computed number depends on, as one line: :data:`PACKAGES` and the
    solvers a method may call (osqp, scs, ecos, IPOPT through cyipopt) and numba (``compiled=True``), each
    ``not installed`` where absent.

    What a cache keys its results by besides the package's own code: an upgrade of any of them is other code.
    (The BLAS kernel is not in it: another kernel changes the rounding of the same code, as another machine
    does, which :func:`environment` records.)
    """
    names = (*PACKAGES, "osqp", "scs", "ecos", "cyipopt-wheels", "cyipopt", "numba")
    return ", ".join([f"python {platform.python_version()}", *(f"{n} {installed_version(n)}" for n in names)])


def git_state(path: Path = PACKAGE_DIR) -> tuple[str | None, bool | None]:
    """The git commit of the checkout ``path`` sits in and whether its files under ``path`` differ from it.

    ``(None, None)`` outside a git checkout or without git.
    """

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(["git", *args], capture_output=True, text=True, cwd=path, timeout=30)
        except (OSError, subprocess.SubprocessError):
            return None
        return done.stdout.strip() if done.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    if not commit:
        return None, None
    status = git("status", "--porcelain", ".")
    return commit, None if status is None else bool(status)


def _blas() -> list[dict[str, Any]]:
    import numpy  # noqa: F401  (loads the BLAS threadpoolctl is to find)
    from threadpoolctl import threadpool_info

    keys = ("internal_api", "version", "architecture", "threading_layer", "num_threads", "filepath")
    libs = [{k: lib.get(k) for k in keys} for lib in threadpool_info() if lib.get("user_api") == "blas"]
    return sorted(libs, key=lambda lib: str(lib["filepath"]))  # in load order otherwise: one machine, two records


@functools.cache
def processor() -> str:
    """The processor's model name: the first ``model name`` of ``/proc/cpuinfo`` (Linux),
    ``machdep.cpu.brand_string`` (macOS), else :func:`platform.processor` (``"unknown"`` if empty).

    Timings of the same code differ between processors of one core count (1.5x between two x86
    machines of this project), so every timing names the processor that made it.
    """
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name") and ":" in line:
                return line.split(":", 1)[1].strip() or "unknown"
    except OSError:
        pass
    if platform.system() == "Darwin":
        try:
            brand = ["sysctl", "-n", "machdep.cpu.brand_string"]
            done = subprocess.run(brand, capture_output=True, text=True, timeout=10)
            if done.returncode == 0 and done.stdout.strip():
                return done.stdout.strip()
        except (OSError, subprocess.SubprocessError):
            pass
    return platform.processor().strip() or "unknown"


def environment() -> dict[str, Any]:
    """The environment of this process: package versions, git commit, platform, BLAS.

    Returns
    -------
    dict
        ``jko_cvx`` (version), ``git_commit`` and ``jko_cvx_modified`` (:func:`git_state`),
        ``python``, one key per entry of :data:`PACKAGES` (installed versions), ``machine``
        (operating system, release, architecture), ``cpu`` (:func:`processor`), ``cpu_count`` and
        ``blas``: per BLAS library
        loaded, its implementation (``internal_api``), ``version``, kernel ``architecture``,
        threading layer, ``num_threads`` and file.  JSON-serialisable.
    """
    from jko_cvx._version import __version__

    commit, modified = git_state()
    return {
        "jko_cvx": __version__,
        "git_commit": commit,
        "jko_cvx_modified": modified,
        "python": platform.python_version(),
        **{name: installed_version(name) for name in PACKAGES},
        "machine": f"{platform.system()} {platform.release()} {platform.machine()}",
        "cpu": processor(),
        "cpu_count": os.cpu_count(),
        "blas": _blas(),
    }


def environment_line(env: dict[str, Any] | None = None) -> str:
    """One line of Markdown naming ``env`` (default: :func:`environment`), for the head of a report.

    A record without ``cpu`` (written before the processor was recorded) names none.
    """
    env = environment() if env is None else env
    commit = "not a git checkout" if env["git_commit"] is None else str(env["git_commit"])[:12]
    if env["jko_cvx_modified"]:
        commit += " (jko_cvx modified)"
    libs = [f"{b['internal_api']} {b['version']} {b['architecture']} kernel, {b['num_threads']} threads"
            for b in env["blas"]]  # fmt: skip
    blas = "; ".join(libs) or "no BLAS found"
    cpu = f"{env['cpu']}, " if env.get("cpu") else ""
    versions = ", ".join(f"{name} {env[name]}" for name in PACKAGES if name in env)
    return (
        f"*Environment: jko_cvx {env['jko_cvx']} (git {commit}), Python {env['python']}, {versions}; "
        f"BLAS {blas}; {env['machine']}, {cpu}{env['cpu_count']} CPUs.*"
    )


def write_markdown(path: Path, text: str, env: dict[str, Any] | None = None) -> None:
    """Write the Markdown report ``text`` to ``path`` with :func:`environment_line` under its title.

    The line goes after the first line when that is a heading (``# ...``), at the top otherwise.
    """
    line = environment_line(env)
    head, _, rest = text.partition("\n")
    if head.startswith("#"):
        text = f"{head}\n\n{line}\n" + (rest if rest.startswith("\n") else f"\n{rest}")
    else:
        text = f"{line}\n\n{text}"
    Path(path).write_text(text)


def record_csv(*paths: Path, env: dict[str, Any] | None = None) -> None:
    """Record ``env`` (default: :func:`environment`) and the time for each written file in ``paths``.

    The record is :data:`ENVIRONMENT_FILE` in each file's directory: a JSON object from file name
    to ``{"written": ISO time, "environment": {...}}``; other files' entries are kept.  Written
    atomically (a temporary file, then a rename).
    """
    env = environment() if env is None else env
    written = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    by_dir: dict[Path, list[str]] = {}
    for p in map(Path, paths):
        if not p.is_file():
            raise FileNotFoundError(f"paths: {p} is not a file written before its environment is recorded")
        by_dir.setdefault(p.parent, []).append(p.name)
    for folder, names in by_dir.items():
        target = folder / ENVIRONMENT_FILE
        try:
            record = json.loads(target.read_text()) if target.exists() else {}
        except ValueError as exc:
            raise ValueError(f"{target} does not read as JSON ({exc}); remove it or repair it") from exc
        record.update({name: {"written": written, "environment": env} for name in names})
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=".environment.", suffix=".tmp")
        with os.fdopen(fd, "w") as fh:
            json.dump(dict(sorted(record.items())), fh, indent=1, sort_keys=True)
            fh.write("\n")
        os.replace(tmp, target)
