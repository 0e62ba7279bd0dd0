"""The paper's three excitation signals, eqs. (14), (27) and (32)."""

import equinox as eqx
import jax
import numpy as np

from .._misc import check_bool, positive_float, positive_int
from .backlash import MAX_COEFFICIENTS
from .params import gauge_factor


class GiriDesign(eqx.Module):
    """The experiment design of the paper: linear order ``n``, branch size ``m``
    (degree ``m-1``; at least 2, at most 64, a backlash branch's cap) and the amplitude ``h_m`` of
    assumption A4.

    ``h_m`` must exceed the zeros of both branches (A4) so that ``v = +h_m`` puts the
    output on ``P1`` and ``v = -h_m`` on ``P2``.
    """

    n: int = eqx.field(static=True)
    m: int = eqx.field(static=True)
    h_m: float = eqx.field(static=True)

    def __init__(self, n, m, h_m):
        self.n = positive_int(n, "n")
        self.m = positive_int(m, "m")
        # refused here, not by identify_giri once the experiments have been run
        if self.m < 2:
            raise ValueError(
                f"`m` must be an integer >= 2 for the paper's design, got {self.m}: with "
                "m = 1 both branches are constants, the backlash output never follows the "
                "input and the staircase (eq. (32)) identifies nothing."
            )
        if self.m > MAX_COEFFICIENTS:
            raise ValueError(
                f"`m` must be at most {MAX_COEFFICIENTS} (a backlash branch's coefficient cap, "
                f"degree {MAX_COEFFICIENTS - 1}), got {self.m}."
            )
        self.h_m = positive_float(h_m, "h_m")

    @property
    def binary_period(self) -> int:
        """Period ``4n`` of ``v2`` (eq. (27))."""
        return 4 * self.n

    @property
    def staircase_period(self) -> int:
        """Period ``2m(n+1)`` of ``v3`` (eq. (32))."""
        return 2 * self.m * (self.n + 1)

    def staircase_levels(self) -> np.ndarray:
        """The ``2m`` plateau levels of ``v3`` actually applied by eq. (32), ``j = 0..2m-1``:
        ``h_m + j h_m/m`` (rising, on ``P1``), then ``-h_m - (j-m) h_m/m`` (falling, on ``P2``)."""
        j = np.arange(2 * self.m)
        step = self.h_m / self.m
        return np.where(j < self.m, self.h_m + j * step, -self.h_m - (j - self.m) * step)

    def check_model(self, model, name: str = "model", *, assumptions: bool = False) -> None:
        """Raise if ``model``'s orders do not match the design (``na = nb = n``, ``m``).

        With ``assumptions=True`` a true system is also checked against what the method
        needs (``ValueError`` naming the assumption): A3 (``A`` stable), A5
        (``B(1) != 0``), branches that do not cross on the excited range
        ``[-2 h_m, 2 h_m]`` (where they cross, the rising and falling branches swap and
        ``HB(P1, P2)`` is no longer the paper's backlash), and A4 in the form the
        estimator uses: ``v = +h_m`` puts the output on ``P1`` and ``v = -h_m`` on ``P2``
        (``mu = P2(-h_m) - P1(h_m)`` has the sign that crosses the gap, section 4.1).
        """
        from .model import Hammerstein

        if not isinstance(model, Hammerstein):
            raise TypeError(f"`{name}` must be an hbjax.Hammerstein, got {type(model).__name__}.")
        na, nb, m = model.arx.na, model.arx.nb, model.backlash.m
        if (na, nb, m) != (self.n, self.n, self.m):
            raise ValueError(
                f"`{name}` has orders na={na}, nb={nb}, m={m} but the design expects "
                f"na = nb = n = {self.n} and m = {self.m}."
            )
        if check_bool(assumptions, "assumptions"):
            self._check_assumptions(model, name)

    def _check_assumptions(self, model, name: str) -> None:
        b = np.asarray(model.arx.b)
        radius = model.arx.pole_radius()
        if not radius < 1:
            raise ValueError(
                f"`{name}` has an unstable A (largest pole modulus {radius:.4g}); "
                "assumption A3 asks all poles strictly inside the unit circle."
            )
        if abs(b.sum()) <= 1e-12 * np.abs(b).sum():
            raise ValueError(f"`{name}` has B(1) = 0; assumption A5 asks a nonzero static gain.")
        c1, c2 = np.asarray(model.backlash.c1), np.asarray(model.backlash.c2)
        grid = np.linspace(-2 * self.h_m, 2 * self.h_m, 4097)
        gap = np.polynomial.polynomial.polyval(grid, c2 - c1)
        if gap.min() < 0 < gap.max():
            where = grid[np.flatnonzero(np.diff(np.sign(gap)))[0]]
            raise ValueError(
                f"the branches P1, P2 of `{name}` cross near v = {where:.4g}, inside the "
                f"excited range [-2 h_m, 2 h_m] = [{-2 * self.h_m:g}, {2 * self.h_m:g}]: "
                "P1 - P2 changes sign, so the rising and falling branches swap sides and "
                "HB(P1, P2) is not a backlash band there."
            )
        side = np.sign(gap[np.argmax(np.abs(gap))])  # +1: P1 below P2 (increasing backlash)
        with jax.ensure_compile_time_eval():
            mu = float(gauge_factor(c1, c2, self.h_m))
        if not mu * side < 0:
            raise ValueError(
                f"`{name}` with h_m = {self.h_m:g}: v = +h_m does not put the output on P1 "
                f"and v = -h_m on P2 (mu = P2(-h_m) - P1(h_m) = {mu:.4g}); the +-h_m swing "
                "must cross the backlash gap (assumption A4): increase `h_m`."
            )

    def constant_input(self, T) -> np.ndarray:
        """``v1``, eq. (14): ``v1(0) = 0`` and ``v1(t) = h_m`` for ``t > 0``."""
        T = positive_int(T, "T", minimum=2)
        v = np.full(T, self.h_m)
        v[0] = 0.0
        return v

    def binary_input(self, T) -> np.ndarray:
        """``v2``, eq. (27): ``-h_m`` where ``t mod 4n == 2n``, else ``+h_m``."""
        T = positive_int(T, "T", minimum=self.binary_period)
        t = np.arange(T)
        return np.where(t % self.binary_period == 2 * self.n, -self.h_m, self.h_m)

    def binary_internal(self, T) -> np.ndarray:
        """``u~2``, eq. (28): 1 exactly where ``v2 = -h_m``, else 0."""
        T = positive_int(T, "T", minimum=self.binary_period)
        return (np.arange(T) % self.binary_period == 2 * self.n).astype(float)

    def staircase_input(self, T) -> np.ndarray:
        """``v3``, eq. (32): with ``t = 2m(n+1)k + j(n+1) + i``, ``0 <= i <= n``, the
        level ``j`` of :meth:`staircase_levels` is held for ``n+1`` samples."""
        T = positive_int(T, "T", minimum=self.staircase_period)
        j = (np.arange(T) % self.staircase_period) // (self.n + 1)
        return self.staircase_levels()[j]

    def estimation_instants(self, T) -> tuple[np.ndarray, np.ndarray]:
        """Last sample ``t = 2m(n+1)k + j(n+1) + n`` of every complete plateau of ``v3``
        within ``T`` samples, with its level index ``j`` (``docs/conventions.md``)."""
        T = positive_int(T, "T", minimum=self.staircase_period)
        start = np.arange(0, T, self.n + 1)
        t = start + self.n
        keep = t < T
        return t[keep], (start[keep] // (self.n + 1)) % (2 * self.m)
