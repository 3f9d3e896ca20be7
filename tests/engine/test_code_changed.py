"""A process whose package files were edited after it imported them neither runs nor records a run: the code it
computes with (imported) and the code on disk (what a fingerprint read now would name) differ."""

import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import jko_cvx

SCRIPT = textwrap.dedent(
    """
    import sys
    sys.path.insert(0, sys.argv[1])
    import jko_cvx
    from jko_cvx import default_scene, simulate
    from jko_cvx.environment import CodeChangedError, code_fingerprint
    assert jko_cvx.__file__.startswith(sys.argv[1]), jko_cvx.__file__
    scene = default_scene().replace({"t_end": 0.02, "v.n": 41})
    before = code_fingerprint()
    if sys.argv[3] == "edit":
        loop = sys.argv[1] + "/jko_cvx/engine/loop.py"
        open(loop, "a").write("\\n# an edit after import\\n")
    try:
        simulate(scene, out=None if sys.argv[4] == "memory" else sys.argv[2])
    except CodeChangedError as exc:
        print("refused:", exc)
    else:
        print("ran", code_fingerprint() == before)
    """
)


def _run(tmp_path: Path, mode: str, where: str = "disk") -> str:
    copy = tmp_path / f"pkg_{mode}_{where}"
    shutil.copytree(Path(jko_cvx.__file__).parent, copy / "jko_cvx", ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp_path / f"run_{mode}"
    argv = [sys.executable, "-c", SCRIPT, str(copy), str(out), mode, where]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300, check=True)
    return done.stdout + str(sorted(p.name for p in out.iterdir()) if out.exists() else "no run directory")


def test_a_package_edited_after_import_is_refused_before_anything_is_written(tmp_path):
    assert _run(tmp_path, "keep").startswith("ran True")
    edited = _run(tmp_path, "edit")
    assert "refused: jko_cvx's files in" in edited and "changed since this process imported them" in edited
    assert edited.endswith("no run directory")


def test_a_run_in_memory_is_refused_too_its_record_would_name_the_imported_code():
    """A run kept in memory records the code that made it (Run.made_by, exported with it): the same check."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        edited = _run(Path(tmp), "edit", "memory")
    assert "refused: jko_cvx's files in" in edited and "changed since this process imported them" in edited
