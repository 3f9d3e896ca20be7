"""The diagnostics count the slices where Newton's second start returned a lower certified J."""

import numpy as np

from jko_cvx import shipped_scene, simulate


def test_the_diagnostics_count_the_slices_where_the_second_start_won():
    """sec:ibu's two bumps (gamma = 3): one slice of the fifth step jams and its second start certifies a J
    1.5e-9 lower; without the second start the column stays 0, and the runs agree bit for bit up to that step."""
    on = simulate(shipped_scene("ibu_gamma3", {"t_end": 0.06}))
    off = simulate(shipped_scene("ibu_gamma3", {"t_end": 0.06, "collision.options.second_start": False}))
    won = on.diagnostics["lower_minimum"].to_numpy()
    assert won.sum() >= 1 and won[0] == 0
    assert (off.diagnostics["lower_minimum"] == 0).all()
    k = int(np.flatnonzero(won)[0])
    assert on.diagnostics["max_f"].iloc[:k].equals(off.diagnostics["max_f"].iloc[:k])
    assert not np.array_equal(on.f, off.f)


def test_other_methods_record_zero():
    run = simulate(shipped_scene("ibu_gamma3", {"t_end": 0.02, "v.n": 41, "collision.method": "sqp"}))
    assert (run.diagnostics["lower_minimum"] == 0).all()
