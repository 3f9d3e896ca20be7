"""Exact restoration of mass and momentum after an interpolation (remap, projection).

The collision operator conserves mass and momentum on every x-slice,
:math:`\\int Q(f)\\,dv = \\int v\\,Q(f)\\,dv = 0` (``prop:properties``).  Interpolating f onto
a new velocity grid (``eqn:mass_conserv_v``) keeps mass by a rescaling; this module adds
the first moment by an exponential tilt,

.. math::

    \\tilde f_j = \\alpha\\, f_j\\, e^{\\beta (v_j - \\bar v)}, \\qquad
    \\bar v = \\frac{\\sum_j v_j h_j f_j}{\\sum_j h_j f_j},

with :math:`\\beta` the root of the (increasing) tilted mean
:math:`\\sum_j v_j h_j f_j e^{\\beta(v_j - \\bar v)} / \\sum_j h_j f_j e^{\\beta(v_j - \\bar v)} = P/M`
and :math:`\\alpha` the paper's mass rescaling.  The tilt is the smallest change of f in
relative entropy that meets both moments (the I-projection); it keeps f positive whatever
the correction, and for the O(interpolation error) corrections met in practice it is the
linear correction :math:`1 + \\beta (v - \\bar v)` to first order.  (A linear correction
turns negative in the floor-level tails of concentrated slices, where
:math:`|v - \\bar v|` is large against the slice's width: measured on
``inhom_gamma3_lambda10``, where refusing it there let the momentum drift to 3e-10.)
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["restore_moments", "restore_three_moments"]

_MAX_NEWTON = 60
_MAX_EXPONENT = 600.0  # bound on |beta (v - vbar)|: keeps the bracket finite


def restore_moments(
    f: NDArray[np.float64],
    h: NDArray[np.float64],
    v: NDArray[np.float64],
    mass: NDArray[np.float64] | float,
    momentum: NDArray[np.float64] | float | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Rescale each row of ``f`` (last axis = velocity) to the given mass and first moment.

    Parameters
    ----------
    f : ndarray, shape (..., N)
        Non-negative densities at the grid points ``v`` with quadrature weights ``h``.
    h : ndarray, shape (N,)
        Quadrature weights.
    v : ndarray, shape (N,) or (..., N)
        The coordinate whose first moment is restored: the grid points, or one row of
        coordinates per row of ``f`` (a periodic axis cut at a different place per row,
        see :func:`jko_cvx.refine.remap_periodic`).
    mass : float or ndarray, shape (...)
        Target :math:`\\sum_j h_j f_j` per row.
    momentum : float or ndarray, shape (...), optional
        Target :math:`\\sum_j v_j h_j f_j` per row; ``None`` restores the mass only.

    Returns
    -------
    f : ndarray, shape (..., N)
        The corrected densities (positive wherever ``f`` is).
    momentum_restored : ndarray of bool, shape (...)
        False where the target mean velocity ``momentum / mass`` is not reachable by a
        tilt of the row (outside its support, or a row without mass): only the mass was
        restored there.
    """
    f = np.asarray(f, dtype=float)
    m0 = np.asarray(f @ h)
    alpha = np.divide(mass, m0, out=np.ones_like(m0), where=m0 > 0)
    if momentum is None:
        return f * alpha[..., None], np.ones(m0.shape, dtype=bool)
    target = np.divide(momentum, mass, out=np.zeros_like(m0), where=np.asarray(mass) > 0)
    v = np.asarray(v, dtype=float)
    first = f @ (v * h) if v.ndim == 1 else np.sum(f * (v * h), axis=-1)
    vbar = np.divide(np.asarray(first), m0, out=np.zeros_like(m0), where=m0 > 0)
    dv = v - vbar[..., None]
    goal = target - vbar  # the tilted mean of dv must reach this
    var = np.asarray(np.sum(h * f * dv * dv, axis=-1))
    beta = np.divide(goal, var, out=np.zeros_like(var), where=var > 0)  # linear guess
    span = np.abs(dv).max(axis=-1)
    limit = _MAX_EXPONENT / np.maximum(span, np.finfo(float).tiny)
    lo, hi = -limit, limit.copy()  # the tilted mean is increasing in beta: keep a bracket
    ok = (m0 > 0) & (var > 0)
    tol = 4 * np.finfo(float).eps * np.maximum(span, 1e-300)
    err = np.full_like(m0, np.inf)
    for _ in range(_MAX_NEWTON):
        beta = np.where((beta > lo) & (beta < hi), beta, 0.5 * (lo + hi))
        mean, tvar = _tilted_mean_var(f, h, dv, beta)
        err = mean - goal
        if np.all(~ok | (np.abs(err) <= tol)):
            break
        lo = np.where(err < 0, beta, lo)
        hi = np.where(err > 0, beta, hi)
        beta = beta - np.divide(err, tvar, out=np.zeros_like(err), where=tvar > 0)
    ok &= np.abs(err) <= 1e-12 * np.maximum(span, 1e-300)
    expo = beta[..., None] * dv
    tilt = np.where(ok[..., None], np.exp(expo - expo.max(axis=-1, keepdims=True)), 1.0)
    g = f * tilt
    g *= np.divide(mass, np.asarray(g @ h), out=np.ones_like(m0), where=(g @ h) > 0)[..., None]
    return g, ok


def _tilted_mean_var(f, h, dv, beta):
    """Mean and variance of ``dv`` under the weights ``h f exp(beta dv)`` (shifted exponent: no overflow)."""
    expo = beta[..., None] * dv
    w = h * f * np.exp(expo - expo.max(axis=-1, keepdims=True))
    w0 = w.sum(axis=-1)
    mean = np.divide((w * dv).sum(axis=-1), w0, out=np.zeros_like(w0), where=w0 > 0)
    c = dv - mean[..., None]
    var = np.divide((w * c * c).sum(axis=-1), w0, out=np.zeros_like(w0), where=w0 > 0)
    return mean, var


def restore_three_moments(
    f: NDArray[np.float64],
    h: NDArray[np.float64],
    v: NDArray[np.float64],
    mass: NDArray[np.float64] | float,
    momentum: NDArray[np.float64] | float,
    moment2: NDArray[np.float64] | float,
    max_iter: int = 30,
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Restore mass, first and second moment of each row by a quadratic exponential tilt.

    .. math::

        \\tilde f_j = \\alpha f_j \\exp\\big(b_1 d_j + b_2 d_j^2\\big), \\qquad d_j = v_j - \\bar v,

    the I-projection of f onto the rows with the given :math:`\\sum h f`, :math:`\\sum v h f`
    and :math:`\\sum v^2 h f`: positive, and to first order the correction
    :math:`1 + b_1 d + b_2 d^2`.  :math:`(b_1, b_2)` by Newton on the tilted moments (the
    Jacobian is the tilted covariance of :math:`(d, d^2)`), with backtracking on the
    residual.  Rows where it does not converge to :math:`10^{-12}` relative (target out of
    reach, or a row without mass) fall back to :func:`restore_moments` (mass and momentum)
    and are reported False.

    Parameters
    ----------
    f, h, v, mass, momentum
        As in :func:`restore_moments` (``v`` the grid points, shape (N,)).
    moment2 : float or ndarray, shape (...)
        Target :math:`\\sum_j v_j^2 h_j f_j` per row.

    Returns
    -------
    f : ndarray, shape (..., N)
    restored : ndarray of bool, shape (...)
    """
    f = np.asarray(f, dtype=float)
    v = np.asarray(v, dtype=float)
    lead = f.shape[:-1]
    F = f.reshape(-1, f.shape[-1])
    M = np.broadcast_to(np.asarray(mass, dtype=float), lead).reshape(-1)
    P = np.broadcast_to(np.asarray(momentum, dtype=float), lead).reshape(-1)
    E = np.broadcast_to(np.asarray(moment2, dtype=float), lead).reshape(-1)
    fallback, _ = restore_moments(F, h, v, M, P)
    out = fallback.copy()
    ok = np.zeros(F.shape[0], dtype=bool)
    for i in range(F.shape[0]):
        g = _tilt2(F[i], h, v, M[i], P[i], E[i], max_iter)
        if g is not None:
            out[i], ok[i] = g, True
    return out.reshape(f.shape), ok.reshape(lead)


def _tilt2(f, h, v, mass, momentum, moment2, max_iter):
    """One row of :func:`restore_three_moments`; None when it does not converge."""
    m0 = f @ h
    if not (m0 > 0 and mass > 0):
        return None
    vbar = (f @ (v * h)) / m0
    d = v - vbar
    goal = np.array([momentum / mass - vbar, moment2 / mass - 2 * vbar * momentum / mass + vbar**2])
    scale = np.array([np.abs(d).max(), np.abs(d).max() ** 2])
    feats = np.stack([d, d * d])
    b = np.zeros(2)

    def residual(b):
        expo = b @ feats
        w = h * f * np.exp(expo - expo.max())
        w /= w.sum()
        mean = feats @ w
        return mean - goal, w, mean

    r, w, mean = residual(b)
    for _ in range(max_iter):
        if np.all(np.abs(r) <= 1e-12 * scale):
            g = f * np.exp(b @ feats - (b @ feats).max())
            return g * (mass / (g @ h))
        c = feats - mean[:, None]
        jac = (c * w) @ c.T
        try:
            step = np.linalg.solve(jac, -r)
        except np.linalg.LinAlgError:
            return None
        lam = 1.0
        while lam > 1e-6:
            r_new, w_new, mean_new = residual(b + lam * step)
            if np.all(np.isfinite(r_new)) and np.linalg.norm(r_new / scale) < np.linalg.norm(r / scale):
                break
            lam /= 2
        else:
            return None
        b, r, w, mean = b + lam * step, r_new, w_new, mean_new
    return None
