"""The paper's three excitation signals, eqs. (14), (27) and (32)."""

import equinox as eqx
import numpy as np

from ._checks import positive_int


def _positive_float(x, name):
    try:
        val = float(x)
    except (TypeError, ValueError):
        raise TypeError(f"`{name}` must be a real number, got {x!r}.") from None
    if not np.isfinite(val) or val <= 0:
        raise ValueError(f"`{name}` must be a finite number > 0, got {x!r}.")
    return val


class GiriDesign(eqx.Module):
    """The experiment design of the paper: linear order ``n``, branch size ``m``
    (degree ``m-1``) and the amplitude ``h_m`` of assumption A4.

    ``h_m`` must exceed the zeros of both branches (A4) so that ``v = +h_m`` puts the
    output on ``P1`` and ``v = -h_m`` on ``P2``.
    """

    n: int = eqx.field(static=True)
    m: int = eqx.field(static=True)
    h_m: float = eqx.field(static=True)

    def __init__(self, n, m, h_m):
        self.n = positive_int(n, "n")
        self.m = positive_int(m, "m")
        self.h_m = _positive_float(h_m, "h_m")

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

    def check_model(self, model, name: str = "model") -> None:
        """Raise if ``model``'s orders do not match the design (``na = nb = n``, ``m``)."""
        from ._model import Hammerstein

        if not isinstance(model, Hammerstein):
            raise TypeError(f"`{name}` must be an hbjax.Hammerstein, got {type(model).__name__}.")
        na, nb, m = model.arx.na, model.arx.nb, model.backlash.m
        if (na, nb, m) != (self.n, self.n, self.m):
            raise ValueError(
                f"`{name}` has orders na={na}, nb={nb}, m={m} but the design expects "
                f"na = nb = n = {self.n} and m = {self.m}."
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
