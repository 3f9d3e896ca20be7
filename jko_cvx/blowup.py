"""Blow-up time with an error bar from a run's own records: fit of max f on the final approach.

Near a finite-time singularity at :math:`T` the largest value of the density grows like a
power of the time left,

.. math:: \\max f(t) \\simeq C\\,(T - t)^{-a}, \\qquad a > 0,

(homogeneous :math:`\\gamma = 1`: :math:`\\max f = \\tfrac12 (T - t)^{-1}` exactly, with
:math:`T = 1/(2\\max f_0)`, ``sec: concentration``), while a concentration without
finite-time collapse grows at most exponentially (:math:`\\gamma = 2`: :math:`\\max f =
e^{Mt}\\max f_0`, the linear contraction).  :func:`fit_blowup` fits both laws to
:math:`\\log\\max f` of the accepted, certified steps and classifies the run.

Window (the final approach), applied in this order:

1. the records are cut at the first uncertified step: a state carried on from a failed
   solve, and everything after it, never enters the fit;
2. the window starts at the first record from which :math:`\\max f \\ge \\rho \\max f(t_0)`
   holds to the end (``growth`` :math:`\\rho = 1.5`): the approach, not the initial layer;
3. the window ends before the first decline of the growth rate
   :math:`r_k = \\log(\\max f_k/\\max f_{k-1})/(t_k - t_{k-1})` below ``1 - rate_drop`` (0.9)
   times its largest value so far that persists for ``RATE_SPAN`` (2) steps: the blow-up law's
   rate :math:`a/(T - t)` only increases, and a record whose growth slows has stopped following
   it (the grid or the regularisation caps max f; past the exact time the record is a
   resolved delta, not the singularity);
4. trailing records whose step grows :math:`\\log\\max f` by more than ``max_step_growth``
   (0.25) are dropped: there the time step no longer resolves the growth, and the implicit
   (JKO) step lags the exact solution by :math:`O(\\Delta t\\, d\\log\\max f/dt)`;
5. at least ``min_points`` (6) records must remain.

Fits: the power law by nonlinear least squares in :math:`\\log\\max f` (profiled over
:math:`T` on a grid, then :func:`scipy.optimize.curve_fit` with :math:`T` bounded to the
horizon :math:`(t_{\\rm last}, t_{\\rm last} + H]`, :math:`H = t_{\\rm last} - t_0` the
record's duration unless given); the exponential law :math:`\\log\\max f = c_0 + c_1 t` by linear least squares.
The two are compared by the Akaike information criterion
:math:`n \\log(\\mathrm{RSS}/n) + 2k` (k = 3 and 2 parameters).

Error bar: the residuals are systematic, not independent noise (the numerical max f lags the
exact one near :math:`T`: the grid resolves the concentration only so far, and the implicit step
lags by :math:`O(\\Delta t)`), so the covariance alone does not cover the error.  The bar is

.. math:: \\sigma_T = k\\,\\bigl(\\sigma_{\\rm fit}^2 + \\delta_{\\rm end}^2 + \\delta_{\\rm half}^2
          + \\delta_{\\rm start}^2 + (c\\,\\Delta t)^2\\bigr)^{1/2},

with :math:`\\sigma_{\\rm fit}` from the covariance of the fit (residual variance scaled),
:math:`\\delta_{\\rm end}` the largest change of :math:`T` over the nested windows that drop up to
a fifth of the records at the end (at most :data:`END_FITS` fits), :math:`\\delta_{\\rm half}`
its change when the window ends where max f reached half its last value,
:math:`\\delta_{\\rm start}` the largest change when the window starts later
(:data:`START_GROWTHS`), :math:`\\Delta t` the window's last step, and :math:`k` =
:data:`ERR_SCALE`, :math:`c` = :data:`DT_SCALE` calibrated on homogeneous :math:`\\gamma = 1` runs
with exact :math:`T` for a nominal 90 % coverage (the repository's validation study fits them on
one set of data and measures the coverage on held-out data).  The bar is symmetric; the error
it covers is mostly a positive bias (:math:`T` late).

Kinds: ``"finite_time"`` when the power law's :math:`T` lies inside the horizon (below 95 %
of it), :math:`a > 2\\sigma_a`, :math:`\\sigma_T < H/4`, the power law beats the
exponential by more than 2 in AIC, max f grows at least :data:`WINDOW_GROWTH`-fold over the
fitted records (less is too little of the approach to extrapolate to a singularity: a slow
bounded rise fits a power law with a small :math:`a` as well), and no record after
:math:`T + \\sigma_T` has max f below :data:`RELAX_FACTOR` times the window's last value (the
run went on past the fitted time and the concentration relaxed: a rise and relax, not a
singularity; a grid that no longer resolves a real collapse holds max f at its cap instead).
Otherwise ``"no_finite_time"`` -- unless the only failures are the width of the error bar,
the window's growth, or a :math:`T` at the horizon where the power law beats the exponential
(``"undetermined"``: the records neither show nor exclude the collapse; growth that accelerates
as a power law's towards a time past the record's reach is no evidence against one, and neither is
an exponential that fits as well while the growth rate still rises by more than
:data:`RATE_RISE_OPEN` over the fitted records), or the
records are too few, too noisy (rms residual of the better law above ``noise``), show no
concentration, or the run stopped early (``stopped_early``: a solver failure, no step,
uncertified steps), in which case ``"undetermined"``; a truncated record cannot exclude a
later collapse.  A record whose max f peaked at :data:`WINDOW_GROWTH` :math:`\\rho \\max f(t_0)` or
more and fell back below :math:`\\rho \\max f(t_0)` and below :data:`RELAX_FACTOR` times its peak by
its end is ``"no_finite_time"`` (``"undetermined"`` when stopped early): the rise is fitted as
above, and the fall back contradicts a singularity more strongly than a relaxation after
:math:`T` does (a smaller dip below :math:`\\rho \\max f(t_0)` shows no concentration to fit).

The fitted :math:`T` estimates a blow-up time only where :attr:`BlowupFit.located` holds (a
power law with :math:`T` inside the horizon, records not too noisy, nothing in them against the
singularity); a run's verdict carries ``T_b_fit`` there and nowhere else, and the reason keeps
the numbers.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import curve_fit

from jko_cvx._numbers import real_array

__all__ = ["KINDS", "BlowupFit", "ThresholdExtrapolation", "extrapolate_thresholds", "fit_blowup"]

KINDS = ("finite_time", "no_finite_time", "undetermined")
RATE_SPAN = 2
END_FRACTION = 5
"""The nested windows of the error bar drop up to ``n // END_FRACTION`` trailing records ..."""
END_FITS = 8
"""... in at most ``END_FITS`` evenly spaced counts."""
START_GROWTHS = (1.5, 2.25, 2.7)
"""The later starts of the error bar: max f above ``g * growth * max f(t_0)`` (growth 1.5: 2.25, 3.4, 4 max f0)."""
ERR_SCALE = 1.6
"""k of the error bar; calibrated for a nominal 90 % coverage of exact gamma = 1 blow-up times."""
DT_SCALE = 0.25
"""c of the error bar: the time step's share (the implicit step's lag)."""
FIRST_ORDER_LAG = 7.0
"""The first-order step's lag per unit :math:`|\\gamma - 1|` (:meth:`BlowupFit.with_step_lag` with
:math:`c = 7|\\gamma - 1|`): homogeneous :math:`\\gamma = 1` moves mass along straight characteristics (Burgers in
the cumulative distribution), so an implicit step adds no lag at a concentration that stays put and
:data:`DT_SCALE` was calibrated there; other :math:`\\gamma` curve them.  Measured on ``tab_bu_g1``'s datum
(121 points, first order at dt = 0.01 and 0.005 against second order at dt = 0.005): lags of -1.3 to -1.4 dt
(:math:`\\gamma = 0.75`), +1.6 to +1.8 dt (1.25), +5.0 to +5.3 dt (1.5), up to +6.2 dt (1.75), at most
10.6 :math:`|\\gamma - 1|\\,dt`; :data:`ERR_SCALE` times 7 covers it."""
WINDOW_GROWTH = 1.5
"""``finite_time`` needs max f to grow at least this factor over the fitted records (tab:g2bu at
lambda = 50, a bounded rise to t = 0.2, fits a power law to a 1.26-fold window; the two-bump g4
approach ends its window at a 1.98-fold rise with T within 0.005 of the exact 0.5)."""
RELAX_FACTOR = 0.5
"""A record after :math:`T + \\sigma_T` with max f below this fraction of the window's last value: relaxed."""
RATE_RISE_OPEN = 0.05
"""An exponential that fits as well is no evidence against a collapse where the growth rate of max f still
rises by more than this fraction over the fitted records (the rate of a quadratic fit of :math:`\\log\\max f`
at the window's ends): super-exponential growth, as :math:`\\gamma = 1.9` short of its collapse (+25 to +31 %
from t = 0.3 to 2 on the g1 datum), where :math:`\\gamma = 2` (the linear contraction) holds its rate within
3 % and :math:`\\gamma \\ge 2.25` saturates (-10 %)."""


@dataclass(frozen=True)
class BlowupFit:
    """The fit of :func:`fit_blowup`.

    Attributes
    ----------
    T_b_fit, T_b_fit_err : float or None
        The power law's :math:`T` and its error bar (None unless a power law was fitted).
    blowup_rate, blowup_rate_err : float or None
        The exponent :math:`a` and its standard error from the covariance.
    log_C : float or None
        :math:`\\log C` of the power law (to draw the fit).
    blowup_kind : str
        One of :data:`KINDS`.
    reason : str
        Why that kind, in words (with the numbers).
    window : tuple of int or None
        ``(start, stop)``: the records ``start <= i < stop`` of the arrays given that were fitted.
    T_b_fit_spread, dt_last : float or None
        The error bar's unscaled parts: :math:`(\\sigma_{\\rm fit}^2 + \\delta_{\\rm end}^2 + \\ldots)^{1/2}` and the
        last time step of the window, :math:`\\sigma_T = k (\\ldots + (c\\,\\Delta t)^2)^{1/2}`.
    at_horizon : bool
        The power law's :math:`T` sits at the bound of the horizon (a bound of the fit, not an estimate).
    located : bool
        Whether :attr:`T_b_fit` estimates a blow-up time: a power law with :math:`T` inside the horizon,
        records not too noisy, and nothing in them against the singularity (no exponential that fits as
        well, no insignificant rate, no relaxation).  ``"finite_time"`` fits are located; an
        ``"undetermined"`` one is where only the width of its bar, the size of its rise or an early stop
        left the question open.  A run's verdict carries ``T_b_fit`` only where this holds.
    """

    T_b_fit: float | None
    T_b_fit_err: float | None
    blowup_rate: float | None
    blowup_rate_err: float | None
    log_C: float | None
    blowup_kind: str
    reason: str
    window: tuple[int, int] | None
    T_b_fit_spread: float | None = None
    dt_last: float | None = None
    at_horizon: bool = False
    located: bool = False

    def with_step_lag(self, c: float) -> BlowupFit:
        """The fit with the error bar widened by a time-step lag :math:`c\\,\\Delta t` (inside the root, beside
        :data:`DT_SCALE`'s term); unchanged where no bar was computed or ``c`` is 0.  The kind is not revisited."""
        if not c > 0 or self.T_b_fit_spread is None or self.dt_last is None:
            return self
        err = ERR_SCALE * float(np.hypot(np.hypot(self.T_b_fit_spread, DT_SCALE * self.dt_last), c * self.dt_last))
        return dataclasses.replace(self, T_b_fit_err=err)

    def estimate(self) -> tuple[float | None, float | None, float | None]:
        """``(T_b_fit, T_b_fit_err, blowup_rate)`` where the fit is :attr:`located`, else three None."""
        return (self.T_b_fit, self.T_b_fit_err, self.blowup_rate) if self.located else (None, None, None)

    def curve(self, t: ArrayLike) -> np.ndarray:
        """The fitted :math:`C (T - t)^{-a}` at ``t < T`` (NaN elsewhere)."""
        if self.T_b_fit is None:
            raise ValueError("no power law was fitted")
        t = np.asarray(t, dtype=float)
        left = self.T_b_fit - t
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(left > 0, np.exp(self.log_C - self.blowup_rate * np.log(np.where(left > 0, left, 1.0))),
                            np.nan)  # fmt: skip


def _undetermined(reason: str, window: tuple[int, int] | None = None) -> BlowupFit:
    return BlowupFit(None, None, None, None, None, "undetermined", reason, window)


def _window_spread(
    t: np.ndarray, m: np.ndarray, start: int, stop: int, T: float, T_max: float,
    growth: float, max_step_growth: float, rate_drop: float, min_points: int,
) -> float:  # fmt: skip
    """T's shifts on the other windows (module docstring): :math:`(\\delta_{\\rm end}^2 + \\ldots)^{1/2}`."""
    n = stop - start

    def shift(i0: int, i1: int) -> float:  # |T(window t[i0:i1]) - T|, 0 when too short or not fitted
        if i1 - i0 < min_points:
            return 0.0
        alt = _fit_power(t[i0:i1], np.log(m[i0:i1]), T_max)
        return 0.0 if alt is None else abs(float(alt[0][2]) - T)

    drops = np.unique(np.linspace(1, max(1, n // END_FRACTION), min(END_FITS, max(1, n // END_FRACTION))).round())
    d_end = max((shift(start, stop - int(j)) for j in drops), default=0.0)
    half = int(np.searchsorted(m[start:stop], m[stop - 1] / 2, side="right"))  # m sorted enough on the approach
    d_half = shift(start, start + half) if half < n - 1 else 0.0
    d_start = 0.0
    for g in START_GROWTHS:
        later = _window(t[:stop], m[:stop], g * growth, max_step_growth, rate_drop)
        if not isinstance(later, str) and later[0] > start:
            d_start = max(d_start, shift(later[0], stop))
    return float(np.sqrt(d_end**2 + d_half**2 + d_start**2))


def _power(t: np.ndarray, log_c: float, a: float, T: float) -> np.ndarray:
    return log_c - a * np.log(np.maximum(T - t, 1e-300))


def _aic(rss: float, n: int, k: int) -> float:
    return n * np.log(max(rss / n, 1e-30)) + 2 * k


def _fit_power(t: np.ndarray, y: np.ndarray, T_max: float) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(log C, a, T), covariance and RSS of the power law with T in (t[-1], T_max]; None if it fails."""
    t_last = t[-1]
    # profile: for fixed T the law is linear in (log C, a); a geometric grid of T - t_last
    gaps = np.geomspace(1e-6 * (T_max - t[0]), T_max - t_last, 400)
    x = -np.log(t_last + gaps[:, None] - t[None, :])  # one row per trial T
    xm = x.mean(axis=1, keepdims=True)
    a_all = ((x - xm) @ (y - y.mean())) / np.sum((x - xm) ** 2, axis=1)
    c_all = y.mean() - a_all * xm[:, 0]
    rss_all = np.sum((c_all[:, None] + a_all[:, None] * x - y) ** 2, axis=1)
    j = int(np.argmin(rss_all))
    best = (float(rss_all[j]), np.array([c_all[j], a_all[j]]), float(t_last + gaps[j]))
    _, coef, T0 = best
    lo = [-np.inf, -np.inf, t_last + 1e-9 * (T_max - t[0])]
    hi = [np.inf, np.inf, T_max]
    p0 = [coef[0], coef[1], min(max(T0, lo[2] * (1 + 1e-15) + 1e-15), T_max)]
    try:
        p, cov = curve_fit(_power, t, y, p0=p0, bounds=(lo, hi), method="trf", x_scale="jac", max_nfev=2000)
    except (RuntimeError, ValueError):
        return None
    rss = float(np.sum((_power(t, *p) - y) ** 2))
    if rss > best[0] * (1 + 1e-9):  # the local refinement lost to the profile: keep the profile's point
        p = np.array([coef[0], coef[1], T0])
        rss = best[0]
    return p, cov, rss


def _window(
    t: np.ndarray, m: np.ndarray, growth: float, max_step_growth: float, rate_drop: float
) -> tuple[int, int] | str:
    """``(start, stop)`` of the final approach in ``m`` (see the module docstring), or why there is none."""
    above = m >= growth * m[0]
    if not above[-1]:
        return f"no concentration to fit: max f grew by a factor {m[-1] / m[0]:.3g} < {growth:g}"
    below = np.flatnonzero(~above)
    start = 0 if below.size == 0 else int(below[-1]) + 1
    stop = m.size
    # the blow-up law's growth rate only increases: the window ends before its first decline
    # (a decline that persists for RATE_SPAN steps: a remap's one-step kink is not one)
    rate = np.diff(np.log(m)) / np.diff(t)  # rate[k - 1]: the step ending at record k
    peak = -np.inf
    for k in range(start + 1, m.size):
        if np.all(rate[k - 1 : k - 1 + RATE_SPAN] < (1 - rate_drop) * peak):
            stop = k - 1
            break
        peak = max(peak, rate[k - 1])
    while stop - start > 1 and np.log(m[stop - 1] / m[stop - 2]) > max_step_growth:
        stop -= 1
    return start, stop


def _paired_records(name_a: str, a: ArrayLike, name_b: str, b: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Two records of real numbers, 1-d and of one length (``ValueError`` / ``TypeError`` naming them)."""
    x, y = real_array(name_a, a), real_array(name_b, b)
    if x.ndim != 1 or y.shape != x.shape:
        raise ValueError(
            f"{name_a} and {name_b} must be 1-d arrays of one length, got shapes {x.shape} and {y.shape}"
        )
    return x, y


def fit_blowup(
    t: ArrayLike,
    max_f: ArrayLike,
    *,
    certified: ArrayLike | None = None,
    stopped_early: str | None = None,
    growth: float = 1.5,
    max_step_growth: float = 0.25,
    min_points: int = 6,
    horizon: float | None = None,
    noise: float = 0.05,
    rate_drop: float = 0.1,
) -> BlowupFit:
    """Fit :math:`\\max f \\simeq C (T - t)^{-a}` to a run's records and classify it (module docstring).

    Parameters
    ----------
    t, max_f : array_like
        Times (strictly increasing) and max f of the records, from the initial state on.
    certified : array_like of bool, optional
        Whether each record's state came from certified solves; the records are cut at the first
        False.  Default: all certified.
    stopped_early : str, optional
        Why the run ended before its horizon (solver failure, no step, ...): a fit that does not
        show finite-time blow-up is then ``"undetermined"``, not ``"no_finite_time"``.
    growth : float
        :math:`\\rho > 1`: the window starts where max f stays above :math:`\\rho \\max f(t_0)`.
    max_step_growth : float
        Trailing records with :math:`\\log(\\max f_k / \\max f_{k-1})` above this are dropped.
    min_points : int
        The fewest records a fit takes (at least 4: three parameters and one residual).
    horizon : float, optional
        :math:`H`: the power law's T is bounded to :math:`(t_{\\rm last}, t_{\\rm last} + H]`;
        default the record's duration :math:`t_{\\rm last} - t_0`.
    noise : float
        Largest rms residual in :math:`\\log\\max f` of the better law for a classification.
    rate_drop : float
        The window ends where the growth rate falls below ``1 - rate_drop`` times its peak.

    Returns
    -------
    BlowupFit
    """
    t, m = _paired_records("t", t, "max_f", max_f)
    if not (growth > 1 and np.isfinite(growth)):
        raise ValueError(f"growth must be a finite number > 1, got {growth!r}")
    if not max_step_growth > 0:
        raise ValueError(f"max_step_growth must be > 0, got {max_step_growth!r}")
    if isinstance(min_points, bool) or not isinstance(min_points, int) or min_points < 4:
        raise ValueError(f"min_points must be an int >= 4, got {min_points!r}")
    if horizon is not None and not (horizon > 0 and np.isfinite(horizon)):
        raise ValueError(f"horizon must be a finite number > 0 or None, got {horizon!r}")
    if not noise > 0:
        raise ValueError(f"noise must be > 0, got {noise!r}")
    early = f"; the run stopped early ({stopped_early})" if stopped_early else ""
    cut = ""
    if certified is not None:
        ok = np.asarray(certified, dtype=bool)
        if ok.shape != t.shape:
            raise ValueError(f"certified must have the shape of t {t.shape}, got {ok.shape}")
        bad = np.flatnonzero(~ok)
        if bad.size:
            cut = f"; records cut at the first uncertified step (t = {t[bad[0]]:.6g})"
            t, m = t[: bad[0]], m[: bad[0]]
            early = early or "; uncertified steps follow the fitted records"
    if t.size < min_points:
        return _undetermined(f"too few records ({t.size} < {min_points}){cut}{early}")
    if not (np.all(np.isfinite(t)) and np.all(np.diff(t) > 0)):
        raise ValueError("t must be finite and strictly increasing")
    if not (np.all(np.isfinite(m)) and np.all(m > 0)):
        raise ValueError("max_f must be finite and > 0")
    above = m >= growth * m[0]
    peak = float(m.max())
    if not above[-1] and peak >= WINDOW_GROWTH * growth * m[0] and m[-1] < RELAX_FACTOR * peak:
        return _relaxed(t, m, above, cut, early, growth=growth, max_step_growth=max_step_growth,
                        min_points=min_points, horizon=horizon, noise=noise, rate_drop=rate_drop)  # fmt: skip
    win = _window(t, m, growth, max_step_growth, rate_drop)
    if isinstance(win, str):
        return _undetermined(win + cut + early)
    start, stop = win
    n = stop - start
    if n < min_points:
        return _undetermined(
            f"too few records on the final approach (max f above {growth:g} x its first value, up to where its "
            f"growth rate falls): {n} < {min_points}{cut}{early}",
            win,
        )
    tw, y = t[start:stop], np.log(m[start:stop])
    H = float(tw[-1] - t[0]) if horizon is None else float(horizon)
    T_max = tw[-1] + H
    fit = _fit_power(tw, y, T_max)
    A = np.column_stack([np.ones_like(tw), tw])
    c_exp, *_ = np.linalg.lstsq(A, y, rcond=None)
    rss_exp = float(np.sum((A @ c_exp - y) ** 2))
    aic_exp = _aic(rss_exp, n, 2)
    if fit is None:
        return _undetermined(f"the power-law fit did not converge{cut}{early}", win)
    p, cov, rss_pow = fit
    aic_pow = _aic(rss_pow, n, 3)
    rms = np.sqrt(min(rss_pow, rss_exp) / n)
    log_c, a, T = (float(x) for x in p)
    err = np.sqrt(np.clip(np.diag(cov), 0, np.inf)) if np.all(np.isfinite(cov)) else np.full(3, np.inf)
    sig_a, sig_T = float(err[1]), float(err[2])
    spread = _window_spread(t, m, start, stop, T, T_max, growth, max_step_growth, rate_drop, min_points)
    dt_last = float(tw[-1] - tw[-2])
    T_err = ERR_SCALE * float(np.sqrt(sig_T**2 + spread**2 + (DT_SCALE * dt_last) ** 2))
    numbers = (
        f"T = {T:.6g} +- {T_err:.2g}, a = {a:.4g} +- {sig_a:.2g}, AIC power {aic_pow:.1f} / exponential "
        f"{aic_exp:.1f}, {n} records t = {tw[0]:.4g}..{tw[-1]:.4g}, horizon {T_max:.4g}"
    )
    out = {
        "T_b_fit": T,
        "T_b_fit_err": T_err,
        "blowup_rate": a,
        "blowup_rate_err": sig_a,
        "log_C": log_c,
        "T_b_fit_spread": float(np.hypot(sig_T, spread)),
        "dt_last": dt_last,
        "at_horizon": not T < tw[-1] + 0.95 * H,
    }
    if rms > noise:
        why = f"records too noisy (rms residual {rms:.2g} > {noise:g} in log max f)"
        return BlowupFit(**out, blowup_kind="undetermined", reason=f"{why}: {numbers}{cut}{early}", window=win)
    fails = []
    if out["at_horizon"]:
        fails.append("T at the horizon")
    if not a > 2 * sig_a:
        fails.append("a not significantly > 0")
    if not T_err < H / 4:
        fails.append("error bar wider than a quarter of the horizon")
    if not aic_pow < aic_exp - 2:
        fails.append("the exponential law fits as well")
    rise = float(m[stop - 1] / m[start])
    open_question = ["error bar wider than a quarter of the horizon"]
    if aic_pow < aic_exp - 2:  # growth that accelerates as a power law's, towards a T the record cannot reach
        open_question.append("T at the horizon")
    if not rise >= WINDOW_GROWTH:
        open_question.append(f"max f grows only {rise:.3g}-fold over the fitted records (< {WINDOW_GROWTH:g})")
        fails.append(open_question[-1])
    later = m[stop:][t[stop:] > T + T_err]
    if later.size and later.min() < RELAX_FACTOR * m[stop - 1]:
        fails.append(
            f"the concentration relaxed: max f fell to {later.min() / m[stop - 1]:.3g} of its value at the window's "
            f"end after the fitted T + error bar"
        )
    # a T the records argue against is no estimate, even stopped early or accelerating
    located = not [f for f in fails if f not in open_question] and not out["at_horizon"]
    horizon_only = {"T at the horizon", "the exponential law fits as well"}
    if fails and horizon_only & set(fails) and (rise_rate := _rate_rise(tw, y)) > RATE_RISE_OPEN:
        # the record accelerates: a law that only reaches the horizon, or an exponential that fits as well,
        # does not exclude a collapse past it
        fails.append(f"the growth rate still rises ({rise_rate:+.0%} over the fitted records)")
        open_question += [fails[-1], *horizon_only]
    if not fails:
        return BlowupFit(**out, blowup_kind="finite_time", reason=f"power law: {numbers}{cut}{early}", window=win,
                         located=True)  # fmt: skip
    # evidence against a collapse (no significant rate, an exponential that fits as well -- T then sits at the
    # horizon too --, a relaxation after T) makes no_finite_time; a bar too wide, a rise too small, or a power law
    # that beats the exponential towards a T past the horizon leaves the question open
    against = [f for f in fails if f not in open_question]
    kind = "undetermined" if early or not against else "no_finite_time"
    return BlowupFit(**out, blowup_kind=kind, reason=f"{'; '.join(fails)}: {numbers}{cut}{early}", window=win,
                     located=located)  # fmt: skip


def _rate_rise(t: np.ndarray, y: np.ndarray) -> float:
    """Relative change of the growth rate of ``y = log max f`` from the first to the last record, read off a
    quadratic least-squares fit (:data:`RATE_RISE_OPEN`); 0 where the rate at the start is not positive."""
    A = np.column_stack([np.ones_like(t), t, t * t])
    c, *_ = np.linalg.lstsq(A, y, rcond=None)
    r0, r1 = c[1] + 2 * c[2] * t[0], c[1] + 2 * c[2] * t[-1]
    return float((r1 - r0) / r0) if r0 > 0 else 0.0


def _relaxed(
    t: np.ndarray, m: np.ndarray, above: np.ndarray, cut: str, early: str, **options: Any
) -> BlowupFit:
    """A record whose max f peaked at :data:`WINDOW_GROWTH` x ``growth`` times its first value or more and fell
    back below ``growth`` times it and below :data:`RELAX_FACTOR` times its peak by its end.

    The rise (the records up to the last one above ``growth`` times the first) is fitted as any record; the
    fall back is evidence against a singularity (a blow-up law's max f only grows, and past the blow-up the
    grid holds it at its cap): ``"no_finite_time"``, or ``"undetermined"`` for a run stopped early; the fit
    locates no time either way.
    """
    last = int(np.flatnonzero(above)[-1])
    peak = int(np.argmax(m))
    rise = fit_blowup(t[: last + 1], m[: last + 1], **options)
    relax = (
        f"the concentration relaxed: max f rose {m[peak] / m[0]:.3g}-fold by t = {t[peak]:.6g} and fell back to "
        f"{m[-1] / m[0]:.3g} times its first value (below {options['growth']:g}) by t = {t[-1]:.6g}"
    )
    kind = "undetermined" if early else "no_finite_time"
    return dataclasses.replace(rise, blowup_kind=kind, reason=f"{relax}; the rise: {rise.reason}{cut}{early}",
                               located=False)  # fmt: skip


@dataclass(frozen=True)
class ThresholdExtrapolation:
    """The paper's threshold times extrapolated to :math:`\\varepsilon_v \\to 0` (:func:`extrapolate_thresholds`).

    Attributes
    ----------
    T, T_err : float
        The limit :math:`T_0` and its error bar.
    c, p : float
        :math:`T_b(\\varepsilon) = T_0 - c\\,\\varepsilon^p` (:math:`c > 0`: the threshold fires early).
    d : float or None
        The time step's coefficient (:math:`+ d\\,\\Delta t`), None when one step was given.
    n : int
        Number of threshold times fitted.
    """

    T: float
    T_err: float
    c: float
    p: float
    d: float | None
    n: int


def _threshold_law(x: np.ndarray, T: float, c: float, p: float, d: float = 0.0) -> np.ndarray:
    return T - c * x[0] ** p + d * x[1]


def extrapolate_thresholds(
    eps_v: ArrayLike, T_b: ArrayLike, dt: ArrayLike | float | None = None, *, p_range: tuple[float, float] = (0.05, 3.0)
) -> ThresholdExtrapolation:
    """Extrapolate threshold times :math:`T_b(\\varepsilon_v, \\Delta t)` to :math:`\\varepsilon_v, \\Delta t \\to 0`.

    The paper's blow-up time is the first step with :math:`\\min dv < \\varepsilon_v`
    (``sec: numerics``); it fires the earlier the larger :math:`\\varepsilon_v` (before the
    singularity where the Fisher term is weak; a strong one slows the narrowing, and it may fire
    after it).  Least squares fit of

    .. math:: T_b(\\varepsilon, \\Delta t) = T_0 - c\\,\\varepsilon^{p} + d\\,\\Delta t

    (the :math:`d` term only when the runs have more than one :math:`\\Delta t`), a cross-check of
    :func:`fit_blowup` from different information (the mesh, not max f).  Error bar:
    :math:`(\\sigma_{\\rm fit}^2 + \\delta_{\\rm range}^2 + \\Delta t_{\\max}^2)^{1/2}`, with
    :math:`\\delta_{\\rm range}` the change of :math:`T_0` when the largest threshold is left out
    and :math:`\\Delta t_{\\max}` the time quantum of the threshold times (a threshold fires
    within a step).  The bar is not calibrated: on the gamma = 1 runs of
    the validation study it covers the exact time in about 56 % of the runs (the
    law's free exponent over a decade and a half of thresholds biases :math:`T_0` by about
    :math:`10^{-2}`); read an agreement with :func:`fit_blowup` as a check, not a second estimate.

    Parameters
    ----------
    eps_v, T_b : array_like
        Thresholds (> 0, at least three distinct) and their threshold times (finite; a run in
        which a threshold never fired has no time to give).
    dt : float or array_like, optional
        The time step of each threshold time's run (one value for all); default 0 (no quantum).
    p_range : (float, float)
        Bounds of the exponent p.

    Returns
    -------
    ThresholdExtrapolation
    """
    e, tb = _paired_records("eps_v", eps_v, "T_b", T_b)
    if not (np.all(np.isfinite(e)) and np.all(e > 0)):
        raise ValueError(f"eps_v must be finite and > 0, got {e.tolist()}")
    if not np.all(np.isfinite(tb)):
        raise ValueError(f"T_b must be finite (a threshold that never fired has no time), got {tb.tolist()}")
    h = np.broadcast_to(np.asarray(0.0 if dt is None else dt, dtype=float), e.shape).copy()
    if not (np.all(np.isfinite(h)) and np.all(h >= 0)):
        raise ValueError(f"dt must be finite and >= 0, got {np.asarray(dt).tolist()}")
    lo, hi = p_range
    if not 0 < lo < hi < np.inf:
        raise ValueError(f"p_range must be 0 < low < high < inf, got {p_range!r}")
    with_dt = np.unique(h).size > 1
    k = 4 if with_dt else 3
    if np.unique(e).size < 3 or e.size < k + 1:
        raise ValueError(
            f"extrapolate_thresholds needs at least {k + 1} threshold times over >= 3 distinct eps_v "
            f"(the law has {k} parameters), got {e.size} over {np.unique(e).size}"
        )

    def fit(sel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.vstack([e[sel] / e.max(), h[sel]])  # eps scaled to <= 1: c of order the time range
        p0 = [float(tb[sel].max()), float(np.ptp(tb[sel])) or 1e-3, 0.8] + ([0.0] if with_dt else [])
        lo_b = [-np.inf, -np.inf, lo] + ([-np.inf] if with_dt else [])
        hi_b = [np.inf, np.inf, hi] + ([np.inf] if with_dt else [])
        law = _threshold_law if with_dt else (lambda x, T, c, p: _threshold_law(x, T, c, p))
        return curve_fit(law, x, tb[sel], p0=p0, bounds=(lo_b, hi_b), method="trf", max_nfev=5000)

    try:
        p, cov = fit(np.ones(e.size, dtype=bool))
    except (RuntimeError, ValueError) as exc:
        raise RuntimeError(f"the threshold-time fit did not converge: {exc}") from None
    sig = float(np.sqrt(cov[0, 0])) if np.isfinite(cov[0, 0]) else float(np.inf)
    shift = 0.0
    rest = e < e.max()
    if np.unique(e[rest]).size >= 3 and rest.sum() >= k + 1:
        try:
            shift = abs(float(fit(rest)[0][0]) - float(p[0]))
        except (RuntimeError, ValueError):
            shift = float(np.inf)
    err = float(np.sqrt(sig**2 + shift**2 + h.max() ** 2))
    c = float(p[1]) / e.max() ** float(p[2])  # back to unscaled eps
    return ThresholdExtrapolation(float(p[0]), err, c, float(p[2]), float(p[3]) if with_dt else None, int(e.size))
