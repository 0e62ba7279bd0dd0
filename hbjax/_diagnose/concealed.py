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
from .._core.arx import ARX
from .._core.backlash import Backlash
from .._misc import positive_int
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
    if key is not None and not (isinstance(key, jax.Array) and (
            jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key)
            or (key.dtype == jnp.uint32 and key.shape == (2,)))):
        raise TypeError(f"`key` must be a JAX PRNG key or None, got {key!r}.")
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
    sy = float(np.std(y0))
    a, b = np.asarray(base.arx.a), np.asarray(base.arx.b)
    c1, c2 = np.asarray(base.backlash.c1), np.asarray(base.backlash.c2)
    if effect is None:
        return base, base, {}
    if effect == "parameter_mismatch":
        true = Hammerstein(Backlash(c1 - 0.3, c2 + 0.3), ARX(a * 0.9, b * 1.25))
        return true, base, {}
    if effect == "output_saturation":
        upper = float(np.quantile(y0, rng.uniform(0.8, 0.9)))
        return fx.OutputSaturation(base, None, jnp.asarray(upper)), base, \
            {"lower": None, "upper": upper}
    if effect == "input_saturation":
        upper = float(np.quantile(u, rng.uniform(0.75, 0.85)))
        lower = float(np.quantile(u, rng.uniform(0.15, 0.25)))
        return fx.InputSaturation(base, jnp.asarray(lower), jnp.asarray(upper)), base, \
            {"lower": lower, "upper": upper}
    if effect == "extra_delay":
        d = int(rng.integers(2, 5))
        return fx.ExtraDelay(base, d), base, {"delay": d}
    if effect == "unmodeled_dynamics":
        p, z = 0.8, 0.3  # missing pole at 0.8 and zero at 0.3, DC gain kept by the nominal
        A = np.convolve(np.concatenate([[1.0], a]), [1.0, -p])
        B = np.convolve(b, [1.0, -z])
        true = fx.UnmodeledDynamics(Hammerstein(base.backlash, ARX(A[1:-1], B[:-1])),
                                    jnp.asarray(A[-1]), jnp.asarray(B[-1]))
        nominal = Hammerstein(base.backlash, ARX(a, b * (1 - z) / (1 - p)))
        return true, nominal, {"pole": p, "zero": z}
    if effect == "colored_noise":
        rho = float(rng.uniform(0.8, 0.95))
        return fx.ColoredNoise(base, jnp.asarray([-rho, 0.0])), base, {"pole": rho}
    if effect == "offset_drift":
        rate = float(rng.choice([-1, 1]) * 0.6 * sy / n)
        return fx.OffsetDrift(base, jnp.asarray(0.0), jnp.asarray(rate)), base, {"rate": rate}
    if effect == "parameter_change":
        t = int(rng.uniform(0.25, 0.5) * n)
        z = np.zeros_like
        true = fx.ParameterChange(base, t, jnp.asarray(z(a)), jnp.asarray(-0.4 * b),
                                  jnp.asarray(z(c1)), jnp.asarray(z(c2)))
        return true, base, {"time": t}
    if effect == "periodic_disturbance":
        f = float(rng.uniform(0.05, 0.3))
        amp = 0.2 * sy
        return fx.PeriodicDisturbance(base, jnp.asarray(f), jnp.asarray(amp),
                                      jnp.asarray(0.3 * amp)), base, {"frequency": f}
    if effect == "output_nonlinearity":
        center, scale = float(np.mean(y0)), sy
        return fx.OutputNonlinearity(base, jnp.asarray(0.12), jnp.asarray(-0.05), center, scale), \
            base, {"k2": 0.12, "k3": -0.05}
    if effect == "coulomb_friction":
        du = np.abs(np.diff(u))
        width = 0.1 * float(np.median(du[du > 0]))
        force = 0.25 * sy
        return fx.CoulombFriction(base, jnp.asarray(force), width), base, {"force": force}
    if effect == "branch_degree":
        scale = float(np.max(np.abs(v)))
        extra = 0.25 * float(np.max(np.abs(u)))
        return fx.BranchDegree(base, jnp.asarray(extra), jnp.asarray(extra), scale), base, \
            {"c_extra": extra / scale ** base.backlash.m}
    raise ValueError(effect)  # pragma: no cover
