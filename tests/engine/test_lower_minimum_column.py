"""The diagnostics count the slices where Newton's second start returned a lower certified J."""

import numpy as np

from jko_cvx import shipped_scene, simulate
from jko_cvx.collision import newton


def _mark_call(monkeypatch, k: int) -> None:
    """Newton's k-th solve (counting from 1) reports its first slice as one where the second start won."""
    cascade, calls = newton._cascade, []

    def marked(*args, **kwargs):
        res = cascade(*args, **kwargs)
        calls.append(1)
        if len(calls) == k:
            res.info["lower_minimum"] = np.asarray(res.info["lower_minimum"]).copy()
            res.info["lower_minimum"].flat[0] = True
        return res

    monkeypatch.setattr(newton, "_cascade", marked)


def test_the_diagnostics_count_the_slices_where_the_second_start_won(monkeypatch):
    """The column sums the step's ``info["lower_minimum"]``.  sec:ibu's two bumps (gamma = 3) jam one slice of the
    fifth step on some BLAS kernels (OpenBLAS SkylakeX: its second start certifies a J 1.5e-9 lower) and none on
    others (Haswell), so the run is checked as it comes (a win only where a jam and a second start were, and the
    runs with and without the second start equal up to it) and with the solver's mark set on the fifth step."""
    on = simulate(shipped_scene("ibu_gamma3", {"t_end": 0.06}))
    off = simulate(shipped_scene("ibu_gamma3", {"t_end": 0.06, "collision.options.second_start": False}))
    won = on.diagnostics["lower_minimum"].to_numpy()
    assert won[0] == 0 and (off.diagnostics["lower_minimum"] == 0).all()
    if won.any():
        k = int(np.flatnonzero(won)[0])
        assert on.diagnostics["max_f"].iloc[:k].equals(off.diagnostics["max_f"].iloc[:k])
        assert not np.array_equal(on.f, off.f)
    else:
        assert np.array_equal(on.f, off.f)  # no jam, no second start: the same run bit for bit
    _mark_call(monkeypatch, 5)
    marked = simulate(shipped_scene("ibu_gamma3", {"t_end": 0.06}))
    expected = np.maximum(np.eye(7, dtype=int)[5], won)  # one slice per solve: a natural win there is the mark
    np.testing.assert_array_equal(marked.diagnostics["lower_minimum"].to_numpy(), expected)


def test_other_methods_record_zero():
    run = simulate(shipped_scene("ibu_gamma3", {"t_end": 0.02, "v.n": 41, "collision.method": "sqp"}))
    assert (run.diagnostics["lower_minimum"] == 0).all()
