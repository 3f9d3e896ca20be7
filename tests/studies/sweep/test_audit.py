"""``run_sweep(audit=K)``: a forged cache entry whose digest was recomputed too (which the digest
cannot catch) is found by recomputing the point, and nothing is served from it."""

from __future__ import annotations

import hashlib
import json
import time

import pytest

from jko_cvx.cli import main
from jko_cvx.studies.sweep import CacheAuditError, point_key, run_sweep

POINTS = [{"a": float(a)} for a in range(6)]


def square(a):
    return {"y": a * a, "label": f"a={a:g}"}


def timed(a):  # a measured wall time differs between two evaluations; it is not compared
    return {"y": a + 1.0, "seconds": time.perf_counter(), "solve_s": time.perf_counter()}


def _forge(cache, func, point, **changes):
    """Edit an entry's result and recompute its digest, as a deliberate forger would."""
    from jko_cvx.studies.sweep import _canonical

    path = cache / f"{point_key(func, point)}.json"
    entry = json.loads(path.read_text())
    entry["result"].update(changes)
    body = {k: entry[k] for k in ("key", "point", "result")}
    entry["digest"] = hashlib.sha256(_canonical(body).encode()).hexdigest()
    path.write_text(json.dumps(entry))
    return path


def test_a_forged_entry_is_served_without_an_audit_and_caught_by_one(tmp_path):
    cache = tmp_path / "c"
    run_sweep(square, POINTS, cache, "serial", progress=False)
    forged = _forge(cache, square, POINTS[3], y=9.009)
    served = run_sweep(square, POINTS, cache, "serial", progress=False)
    assert served.y.iloc[3] == 9.009  # the digest cannot tell: the threat the audit answers
    with pytest.raises(CacheAuditError, match=rf"1 of 6 recomputed points differ.*{forged.name} \(y: cached 9.009"):
        run_sweep(square, POINTS, cache, "serial", progress=False, audit=6)


def test_an_audit_of_k_points_checks_k_distinct_cached_points_and_reports_the_seed(tmp_path, capsys):
    cache = tmp_path / "c"
    first = run_sweep(square, POINTS, cache, "serial", progress=False)
    capsys.readouterr()
    again = run_sweep(square, POINTS, cache, "serial", progress=False, audit=3, audit_seed=7)
    assert "3 of 6 cached points recomputed, identical bit for bit" in capsys.readouterr().err
    assert again.equals(first.assign(cached=True))
    # the same seed chooses the same points; a forgery among them is always found
    chosen = []
    for p in POINTS:
        path = _forge(cache, square, p, y=-1.0)
        try:
            run_sweep(square, POINTS, cache, "serial", progress=False, audit=3, audit_seed=7)
        except CacheAuditError:
            chosen.append(p["a"])
        _forge(cache, square, p, y=p["a"] ** 2)
        assert path.exists()
    assert len(chosen) == 3


def test_wall_times_are_not_compared_but_everything_else_is(tmp_path):
    cache = tmp_path / "c"
    run_sweep(timed, POINTS[:2], cache, "serial", progress=False)
    run_sweep(timed, POINTS[:2], cache, "serial", progress=False, audit=2)  # times differ: no error
    _forge(cache, timed, POINTS[1], y=2.5)
    with pytest.raises(CacheAuditError, match=r"y: cached 2\.5, recomputed 2\.0"):
        run_sweep(timed, POINTS[:2], cache, "serial", progress=False, audit=2)


def test_an_audit_on_the_process_pool_finds_the_forgery_too(tmp_path):
    cache = tmp_path / "c"
    run_sweep(square, POINTS[:3], cache, "serial", progress=False)
    _forge(cache, square, POINTS[0], label="a=forged")
    with pytest.raises(CacheAuditError, match="label: cached 'a=forged'"):
        run_sweep(square, POINTS[:3], cache, "process", workers=2, progress=False, audit=3)


@pytest.mark.parametrize("audit", [-1, 1.5, True, "2"])
def test_audit_must_be_a_count(tmp_path, audit):
    with pytest.raises(ValueError, match="audit must be an integer >= 0"):
        run_sweep(square, POINTS, tmp_path / "c", "serial", progress=False, audit=audit)
    assert not (tmp_path / "c").exists()


def test_reproduce_audit_on_the_command_line(tmp_path, capsys):
    out = tmp_path / "r"
    args = ["reproduce", "fisher_width", "--quick", "--executor", "serial", "--out", str(out)]
    assert main(args) == 0
    capsys.readouterr()
    assert main([*args, "--audit", "2"]) == 0
    assert "2 of " in capsys.readouterr().err
    assert main([*args, "--audit", "2", "--fresh"]) == 2
