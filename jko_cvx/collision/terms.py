"""The edge terms of the collision objective, each in one place: value, gradient, Hessian.

Per edge :math:`k` (between grid points :math:`k` and :math:`k+1`) with :math:`x = f_k`,
:math:`y = f_{k+1}`, :math:`s = x + y`:

* Wasserstein (``eqn:non-uniform JKO``): :math:`w_k\\, m_k^2 / s_k`, :math:`w_k = 2\\Delta v_k`;
* Fisher information, :math:`c_k\\,\\psi(x, y)`, :math:`c_k = \\Delta t^2/(\\beta^2 \\Delta v_k)`:
  ``"perspective"`` :math:`\\psi = 2 (y - x)^2 / s` (a rotated cone) or ``"log"`` (the paper's)
  :math:`\\psi = \\tfrac12 (\\log y - \\log x)^2 s`.

The energy :math:`\\Delta t\\,\\sigma f^\\top K f` has its home in
:class:`jko_cvx.kernels.EnergyOperator` (``quadratic``, ``matvec``, ``flux_block``).
:class:`~jko_cvx.collision.problem.CollisionProblem` (with domain guards, for any point) and
the Newton solver (interior points, fused) both evaluate the terms through this module,
and :func:`reduced_bands` turns the per-edge Hessian into the bands of the reduced
Hessian :math:`T^\\top H_{ff} T + T^\\top H_{fm} + H_{mf} T + H_{mm}`.  The expressions are
written once so that both callers round alike.
"""

from __future__ import annotations

import weakref
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "FISHER_TERMS",
    "LogFisher",
    "PerspectiveFisher",
    "WassersteinDerivatives",
    "band_coefficients",
    "reduced_bands",
    "wasserstein_derivatives",
    "wasserstein_value",
]

Array = NDArray[np.float64]


def _row(coef: Array, like: Array) -> Array:
    """The per-edge coefficients ``coef`` as a ``(1, n)`` row where ``like`` is a batch ``(B, n)``.

    The same numbers; NumPy then broadcasts no 1-D operand against a 2-D one, which costs
    about as much as the arithmetic itself on arrays of N ~ 100.
    """
    return coef[None] if np.ndim(like) == 2 and np.ndim(coef) == 1 else coef


def wasserstein_value(m: Array, s: Array) -> Array:
    """:math:`m^2/s` per edge (interior: ``s > 0``); the objective weights it by ``2 dv``."""
    return m * m / s


class WassersteinDerivatives(NamedTuple):
    """First and second derivatives of :math:`w\\,m^2/s` per edge (``s`` stands for x and y alike).

    A named tuple: built in every Newton and SQP iteration (0.4 us against a frozen dataclass's 0.65 us).
    """

    g_s: Array  # d/ds = d/dx = d/dy
    g_m: Array
    h_ss: Array
    h_sm: Array
    h_mm: Array


def wasserstein_derivatives(m: Array, s: Array, w: Array) -> WassersteinDerivatives:
    """Derivatives of :math:`w m^2/s` with :math:`u = m/s`: gradient :math:`(-w u^2, 2 w u)`, Hessian
    :math:`(2 w u^2/s, -2 w u/s, 2 w/s)` in :math:`(s, s), (s, m), (m, m)`."""
    w = _row(w, m)
    u = m / s
    w2 = 2 * w
    g_m = w2 * u  # shared: 2 w u u / s is (2 w u) u / s, the same operations in the same order
    # -2 w u / s is not written -(2 w u) / s: the same number, but a NaN would change sign
    return WassersteinDerivatives(-w * u * u, g_m, g_m * u / s, -2 * w * u / s, w2 / s)


class PerspectiveFisher:
    """:math:`\\psi(x, y) = 2 (y - x)^2 / s`: jointly convex, conic; finite at vacuum when x = y."""

    name = "perspective"

    def value(self, x: Array, y: Array, s: Array) -> Array:
        """:math:`\\psi` at interior edges (``s > 0``)."""
        d = y - x
        return 2 * d * d / s

    def guarded_value(self, x: Array, y: Array, s: Array) -> Array:
        """:math:`\\psi` anywhere: 0 on an empty edge, inf where s = 0 but x != y."""
        d = y - x
        return np.where(s > 0, self.value(x, y, np.where(s > 0, s, 1.0)), np.where(d == 0, 0.0, np.inf))

    def gradient(self, x: Array, y: Array, s: Array, c: Array) -> tuple[Array, Array]:
        """:math:`c\\,(\\partial_x\\psi, \\partial_y\\psi) = c(-4r - 2r^2, 4r - 2r^2)`, :math:`r = (y-x)/s`."""
        c = _row(c, s)
        r = (y - x) / s
        return c * (-4 * r - 2 * r * r), c * (4 * r - 2 * r * r)

    def hessian(self, x: Array, y: Array, s: Array, c: Array) -> tuple[Array, Array, Array]:
        """:math:`c\\,(\\psi_{xx}, \\psi_{yy}, \\psi_{xy}) = (16c/s^3)(y^2, x^2, -xy)`."""
        c = _row(c, s)
        k = 16 * c / (s * s * s)
        return k * y * y, k * x * x, -(k * x * y)

    def gradient_and_hessian(
        self, x: Array, y: Array, s: Array, c: Array, mixed: bool = True
    ) -> tuple[Array, Array, Array, Array, Array | None]:
        """:meth:`gradient` and :meth:`hessian`, ``(gx, gy, hxx, hyy, hxy)``, bit for bit.

        The same expressions, the subexpression they share evaluated once (``2 r r``): what
        one Newton iteration needs, at fewer NumPy calls.  ``mixed=False`` leaves ``hxy``
        out (None): the paper's SQP uses the diagonal only.
        """
        c = _row(c, s)
        r = (y - x) / s
        r2 = 2 * r * r
        k = 16 * c / (s * s * s)
        return c * (-4 * r - r2), c * (4 * r - r2), k * y * y, k * x * x, -(k * x * y) if mixed else None


class LogFisher:
    """The paper's :math:`\\psi(x, y) = \\tfrac12 (\\log y - \\log x)^2 s`: a barrier at f = 0."""

    name = "log"

    def value(self, x: Array, y: Array, s: Array) -> Array:
        """:math:`\\psi` for x, y > 0."""
        L = np.log(y) - np.log(x)
        return 0.5 * L * L * s

    def guarded_value(self, x: Array, y: Array, s: Array) -> Array:
        """:math:`\\psi` anywhere: inf unless x, y > 0."""
        ok = (x > 0) & (y > 0)
        return np.where(ok, self.value(np.where(ok, x, 1.0), np.where(ok, y, 1.0), s), np.inf)

    def gradient(self, x: Array, y: Array, s: Array, c: Array) -> tuple[Array, Array]:
        """:math:`c(-L s/x + L^2/2,\\ L s/y + L^2/2)`, :math:`L = \\log y - \\log x`."""
        c = _row(c, s)
        L = np.log(y) - np.log(x)
        return c * (-L * s / x + 0.5 * L * L), c * (L * s / y + 0.5 * L * L)

    def hessian(self, x: Array, y: Array, s: Array, c: Array) -> tuple[Array, Array, Array]:
        """:math:`c\\,(s + L(y-x))/x^2`, :math:`c\\,(s + L(y-x))/y^2`, :math:`c\\,(-s + L(x-y))/(xy)`."""
        c = _row(c, s)
        L = np.log(y) - np.log(x)
        q = c * (s + L * (y - x))
        return q / (x * x), q / (y * y), c * (-s + L * (x - y)) / (x * y)

    def gradient_and_hessian(
        self, x: Array, y: Array, s: Array, c: Array, mixed: bool = True
    ) -> tuple[Array, Array, Array, Array, Array | None]:
        """:meth:`gradient` and :meth:`hessian`, ``(gx, gy, hxx, hyy, hxy)``, bit for bit.

        The same expressions, the subexpressions they share evaluated once (``L``, the two
        logarithms, and ``L^2/2``): what one Newton iteration needs, at fewer NumPy calls.
        ``mixed=False`` leaves ``hxy`` out (None): the paper's SQP uses the diagonal only.
        """
        c = _row(c, s)
        L = np.log(y) - np.log(x)
        half_l2 = 0.5 * L * L
        q = c * (s + L * (y - x))
        return (
            c * (-L * s / x + half_l2),
            c * (L * s / y + half_l2),
            q / (x * x),
            q / (y * y),
            c * (-s + L * (x - y)) / (x * y) if mixed else None,
        )


FISHER_TERMS: dict[str, PerspectiveFisher | LogFisher] = {"perspective": PerspectiveFisher(), "log": LogFisher()}

_BAND_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def band_coefficients(grid, ndim: int = 1) -> tuple:
    """Grid constants of the reduced-Hessian bands (T has columns a_k e_k + b_k e_{k+1}), cached per grid.

    ``(h, a, b, a a, 2 a b, b b, a_k a_{k+1}, b_k a_{k+1}, b_k b_{k+1}, b_k a_{k+2}, 2 (a + b))``.
    ``ndim=2``: the same arrays as ``(1, n)`` rows, the operands for batches ``(B, n)``: the
    same numbers, and NumPy need not broadcast a 1-D operand (measured: the bands of one
    slice at N = 61 in 9 us against 16 us).
    """
    c = _BAND_CACHE.get(grid)
    if c is None:
        h = grid.h
        a, b = -1 / h[:-1], 1 / h[1:]
        pairs = (a[:-1] * a[1:], b[:-1] * a[1:], b[:-1] * b[1:], b[:-2] * a[2:])
        flat = (h, a, b, a * a, 2 * a * b, b * b, *pairs, 2 * (a + b))
        c = {1: flat, 2: tuple(x[None] for x in flat)}
        _BAND_CACHE[grid] = c
    return c[ndim]


def reduced_bands(grid, xx: Array, yy: Array, xy: Array, h_sm: Array, h_mm: Array) -> tuple[Array, Array, Array]:
    """Diagonal, first and second off-diagonal of :math:`Z^\\top \\nabla^2 (\\text{edge terms}) Z`.

    With :math:`T = -\\operatorname{diag}(1/h) D` (columns :math:`a_k e_k + b_k e_{k+1}`,
    :math:`a_k = -1/h_k`, :math:`b_k = 1/h_{k+1}`) and the per-edge Hessian entries (the
    mixed f-m entries of an edge are ``h_sm`` for both of its points), the reduced
    Hessian of the edge terms is pentadiagonal.
    """
    _, a, b, aa, ab2, bb, o1a, o1b, o1c, o2, mixed = band_coefficients(grid, 2 if xx.ndim == 2 else 1)
    d = np.zeros((*xx.shape[:-1], xx.shape[-1] + 1))
    d[..., :-1] += xx
    d[..., 1:] += yy
    diag = h_mm + aa * d[..., :-1] + ab2 * xy + bb * d[..., 1:] + mixed * h_sm
    off1 = (
        o1a * xy[..., :-1]
        + o1b * d[..., 1:-1]
        + o1c * xy[..., 1:]
        + b[..., :-1] * h_sm[..., 1:]
        + a[..., 1:] * h_sm[..., :-1]
    )
    off2 = o2 * xy[..., 1:-1]
    return diag, off1, off2
