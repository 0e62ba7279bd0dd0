"""Test recordings with exactly one concealed effect, for proving the diagnosis.

:func:`concealed_recording` simulates one of a few base HB-Hammerstein systems (different
orders and branch degrees) under one of several operating inputs, hides one effect of
:data:`hbjax.EFFECTS` in it (or none) and returns the recording, the *nominal* model the
user would believe, and the truth for scoring.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from . import effects as fx
from .kernel_effect import signals
from .._core import display
from .._core.arx import ARX
from .._core.backlash import Backlash
from .._misc import check_key, positive_int
from .._core.model import Hammerstein, play_trajectory
from .._core.simulate import simulate

INPUTS = ("steps", "smooth", "sines")


def base_systems() -> list[Hammerstein]:
    """Three base systems: (na, nb, m) = (2, 2, 3), (1, 1, 2) and (3, 2, 4)."""
    return [
        Hammerstein(Backlash([-1.0, 0.9, 0.01], [1.0, 0.9, -0.01]), ARX([-1.2, 0.5], [1.0, 0.5])),
        Hammerstein(Backlash([-0.5, 1.0], [0.5, 1.0]), ARX([-0.8], [0.5])),
        Hammerstein(Backlash([-0.8, 0.6, 0.0, 0.004], [0.8, 0.6, 0.0, 0.004]),
                    ARX([-1.6, 1.0, -0.24], [0.3, 0.2])),
    ]


@dataclasses.dataclass(frozen=True)
class ConcealedRecording:
    """A recording ``(v, y)`` of ``true_model`` with ``effect`` concealed; ``model`` is the
    nominal model given to the diagnosis, ``truth`` the concealed effect's parameters."""

    v: np.ndarray
    y: np.ndarray
    model: Hammerstein
    true_model: object
    effect: str | None
    truth: dict

    def __repr__(self) -> str:
        # as the package's models and results show themselves: large arrays by shape and
        # range, not every sample
        return display.pformat(self)


def _input(kind, n, rng, amp=8.0):
    if kind == "steps":
        out, t = np.empty(n), 0
        while t < n:
            k = int(rng.integers(5, 40))
            out[t:t + k] = rng.uniform(-amp, amp)
            t += k
        return out
    if kind == "smooth":
        w = rng.standard_normal(n + 200)
        x = np.convolve(w, np.hanning(25), mode="same")[100:100 + n]
        return amp * np.clip(x / (2.5 * np.std(x)), -1.0, 1.0)
    if kind == "sines":
        t = np.arange(n)
        f = rng.uniform(0.002, 0.02, 3)
        x = sum(np.sin(2 * np.pi * fk * t + rng.uniform(0, 6.3)) for fk in f)
        return amp * x / np.max(np.abs(x))
    raise ValueError(f"`inputs` must be one of {INPUTS}, got {kind!r}.")


def concealed_recording(effect: str | None, *, system: int = 0, inputs: str = "steps",
                        n: int = 2000, noise: float = 0.03, key=None) -> ConcealedRecording:
    """Simulate a recording with exactly one concealed effect (``None``: a clean one).

    **Arguments:**

    - `effect`: a name of :data:`hbjax.EFFECTS` or ``None``.
    - `system`: index into :func:`base_systems` (0, 1 or 2).
    - `inputs`: operating input, ``"steps"`` (random levels), ``"smooth"`` (low-pass noise)
      or ``"sines"`` (three slow sinusoids).
    - `n`: record length; `noise`: output noise level relative to the output's std.
    - `key`: a ``jax.random`` key (default ``PRNGKey(0)``).
    """
    if effect is not None and effect not in fx.EFFECTS:
        raise ValueError(f"unknown `effect` {effect!r}; known: {sorted(fx.EFFECTS)}.")
    systems = base_systems()
    n = positive_int(n, "n")
    if isinstance(noise, (str, bytes, bool, np.bool_)):
        raise TypeError(f"`noise` must be a real number, got {noise!r}.")
    if not (np.isfinite(float(noise)) and float(noise) >= 0):
        raise ValueError(f"`noise` must be a finite number >= 0, got {noise!r}.")
    check_key(key, optional=True)
    if isinstance(system, bool) or not (isinstance(system, int) and 0 <= system < len(systems)):
        raise ValueError(f"`system` must be an index 0..{len(systems) - 1}, got {system!r}.")
    key = jax.random.PRNGKey(0) if key is None else key
    seed = int(jax.random.randint(key, (), 0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    base = systems[system]
    v = _input(inputs, n, rng)
    y0 = np.asarray(simulate(base, v))
    u = np.asarray(play_trajectory(base.backlash, jnp.asarray(v), 0.0))
    # equation-error std giving `noise` * std(y0) at the output (1/A's impulse response norm)
    h = np.asarray(simulate(Hammerstein(Backlash([0.0], [0.0]), base.arx), np.zeros(200),
                            np.eye(200)[0]))
    xi = noise * np.std(y0) / np.linalg.norm(h) * rng.standard_normal(n)
    true, nominal, truth = _conceal(effect, base, v, y0, u, rng, n)
    y = np.asarray(simulate(true, v, xi))
    return ConcealedRecording(v, y, nominal, true, effect, truth)


def _conceal(effect, base, v, y0, u, rng, n):
    if effect is None:
        return base, base, {}
    return fx.EFFECTS[effect].concealed(base, signals(v, y0, u, n), rng)
