"""The embedded default system used by the demo, the notebooks and the tests."""

from .arx import ARX
from .backlash import Backlash
from .model import Hammerstein
from .signals import GiriDesign


def default_system() -> Hammerstein:
    """An increasing backlash with quadratic branches (m = 3) and a second-order ARX block.

    ``P1(v) = -1 + 0.9 v + 0.01 v^2`` (rising), ``P2(v) = 1 + 0.9 v - 0.01 v^2`` (falling):
    a gap of 2 at ``v = 0`` that stays open on ``[-2 h_m, 2 h_m]`` for ``h_m = 4``;
    ``A = 1 - 1.2 q^-1 + 0.5 q^-2`` (poles of modulus 0.71), ``B = q^-1 + 0.5 q^-2``.
    """
    return Hammerstein(
        Backlash([-1.0, 0.9, 0.01], [1.0, 0.9, -0.01]),
        ARX([-1.2, 0.5], [1.0, 0.5]),
    )


def default_design() -> GiriDesign:
    """``GiriDesign(n=2, m=3, h_m=4)`` matching :func:`default_system` (as in the paper's Fig. 3)."""
    return GiriDesign(2, 3, 4.0)
