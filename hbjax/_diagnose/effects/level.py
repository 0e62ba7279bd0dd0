"""Dynamics whose gain and time constant change with the output level (a tank drained
through an orifice: Torricelli's outflow ~ sqrt(level))."""

from __future__ import annotations

import functools
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._core.model import Hammerstein
from ..effect_base import EffectConstraint
from ..explain import rounded
from .recursive import AbstractRecursiveEffect, arx_scan


class LevelDependentDynamics(AbstractRecursiveEffect):
    """Every pole's rate and the static gain of the linear block scale with the level
    above an outlet.

    At level ``y(t-1)`` the block of eq. (10) runs ``s(t)`` times faster and with ``1/s``
    times its static gain, as a tank drained through an orifice does:

        ``A_s(q^-1) (y(t) - outlet) = g(s) (B(q^-1) u(t) - A(1) outlet)``,
        ``s(t) = (depth / |y(t-1) - outlet|)^alpha``, ``depth = y_mean - outlet``,

    where ``A_s`` has the poles of ``A`` with their continuous-time rates multiplied by
    ``s``: pole ``p`` goes to ``p^s`` (``exp(s log p)``, the exact discrete form of a
    continuous-time pole ``log p`` scaled by ``s``; stable for every ``s > 0``; a
    negative real pole, which has no continuous-time rate, goes to ``-|p|^s``), and
    ``g = A_s(1) / (s A(1))`` sets the static gain to ``1/s`` times the nominal one. In
    equilibrium ``s A(1) (y - outlet) = B(1) u - A(1) outlet``: the outflow goes as
    ``(y - outlet)^(1 - alpha)``, Torricelli's law for ``alpha = 1/2``; locally every time
    constant and the gain grow as ``(y - outlet)^alpha``. ``s = 1`` at the mean level, so
    ``alpha = 0`` is the nominal model. Fitted: ``alpha``, ``log_depth``
    (``depth = exp(log_depth) y_std``) and the ``datum`` (below; ``None``: the outlet).
    ``pole_map="bilinear"`` moves each pole through ``x = (z - 1) / (z + 1)`` instead
    (``p`` to ``(1 + s x_p) / (1 - s x_p)``): the law's form before the matched map, with
    which model files written then still load; it agrees with ``p^s`` for slow poles only.

    The datum is the level the scaled block's input response is measured from: the law
    above with ``datum`` in place of ``outlet`` outside ``s``,
    ``A_s (y - datum) = g (B u - A(1) datum)``. At the outlet (the default) the tank
    drains to its orifice without inflow; at the measured output's zero, the nominal
    block's own origin, the law scales the gain and the time constants of eq. (10) as
    they stand (``A_s y = g B u``), as a gain-scheduled model does. Which one a plant
    follows depends on where its sensor's zero sits, so the fit chooses. With the datum
    fixed at the outlet, 4 of the 24 level-law records of the generator in tests/ that
    are named now were named as the refit (2), a curved sensor or friction instead, and
    2 named then are now the refit's (benchmarks/RESULTS.md). Scaling only the restoring
    term ``y(t-1) - outlet`` (an earlier form of this law) is the same for a first-order
    block but leaves the other poles of a higher-order one in place, and was named on a
    third of such records."""

    base: Hammerstein
    alpha: Float[Array, ""]
    log_depth: Float[Array, ""]
    y_mean: Float[Array, ""]
    y_std: Float[Array, ""]
    datum: Float[Array, ""] | None = None
    pole_map: str = eqx.field(static=True, default="matched")

    name: ClassVar[str] = "level_dependent_dynamics"
    #: the pole map of files written before ``pole_map`` existed: the bilinear one, so
    #: that a saved model simulates as it did (hbjax.load_model)
    file_defaults: ClassVar[dict] = {"pole_map": "bilinear"}
    n_params: ClassVar[int] = 3
    constraints: ClassVar[dict] = {
        "alpha": EffectConstraint(), "log_depth": EffectConstraint(), "y_mean": EffectConstraint(),
        "y_std": EffectConstraint(positive=True), "datum": EffectConstraint(optional=True)}
    # Equation error in a loop reaches the free run through 1/A, and the refit follows a
    # level law closely within the range a record excites: on two strong records of the law
    # from the generator in tests/, the law *at its true parameters* simulated the held-out
    # part at 91.43 % and 96.06 % against the refit's 91.24 % and 95.89 %, not a
    # significant gain, while the fitted law beat the refit by 890 and 215 in BIC. As for
    # unmodeled_dynamics, the held-out one-step prediction gain then counts where the law
    # beats the noise model by the BIC margin: a level-dependent gain and pole set changes
    # the input-to-output dynamics, which no noise model can (benchmarks/RESULTS.md).
    noise_rival: ClassVar[str | None] = "colored_noise"
    # Anchored too (base held at the nominal values, three parameters): where the nominal
    # model is right apart from the law, the joint fit pays for every base parameter and a
    # weak law loses in BIC to an anchored static curve (`output_nonlinearity`, two
    # parameters), which also changes the gain with the level. Before and after on the
    # same records of the generator in tests/ (four full seeds and a level-law seed): the
    # level law named on 22 of 22 records against 17, one parameter_mismatch lost to it,
    # top-1 200 of 210 against 198, no clean record with a finding (benchmarks/RESULTS.md,
    # "the level law's anchored variant, before and after"). Where a record rejects the
    # held base, the base-consistency test refuses the anchored variant and the joint one
    # stands. With the bilinear pole map (`pole_map`) the base was rejected on 4 of 8
    # level-law records of one seed, p down to 1e-76: for fast poles that map is far
    # from the plant's p^s. With the matched map, on 1 of the same 8 (p = 1e-6), the
    # same top findings (benchmarks/RESULTS.md, "the level law's matched pole map").

    @classmethod
    def from_params(cls, base, params, consts=None):
        mean, std = (0.0, 1.0) if consts is None else (consts[1], consts[2])
        mean, std = jnp.asarray(mean), jnp.asarray(std)
        # the datum in units of the output's spread from its mean, as the depth
        return cls(base, params[0], params[1], mean, std, mean + params[2] * std)

    def params(self):
        return jnp.stack([jnp.asarray(self.alpha), jnp.asarray(self.log_depth),
                          (self.datum_level - self.y_mean) / self.y_std])

    def __check_init__(self):
        if self.pole_map not in ("matched", "bilinear"):
            raise ValueError(f"`LevelDependentDynamics.pole_map` must be 'matched' or "
                             f"'bilinear', got {self.pole_map!r}.")

    @property
    def outlet(self):
        return self.y_mean - jnp.exp(self.log_depth) * self.y_std

    @property
    def datum_level(self):
        return self.outlet if self.datum is None else jnp.asarray(self.datum)

    def scaling(self, level):
        """``s`` at output level ``level``. Below the outlet the law continues as its odd
        extension (``s`` from the distance to the outlet): the flow through the orifice
        then changes sign and stays of the same size. Clamping the distance instead
        made ``s`` 1000^alpha there, and a free run that starts below the outlet (every
        simulation from rest of a record whose level sits far from zero) was thrown
        into a growing oscillation."""
        depth = jnp.exp(self.log_depth) * self.y_std
        distance = jnp.maximum(jnp.abs(level - self.outlet), 1e-3 * depth)
        return (depth / distance) ** self.alpha

    def recursion(self, v, u, y_forced, noise):
        a, b = self.base.arx.a, self.base.arx.b
        scaled_a = (_matched_scaling if self.pole_map == "matched" else _bilinear_scaling)(a)
        gain_a = 1.0 + jnp.sum(a)
        datum = self.datum_level

        def law(level):
            s = self.scaling(level)
            a_s = scaled_a(s)
            gain_s = 1.0 + sum(a_s)            # A_s(1)
            g = gain_s / (s * gain_a)          # static gain 1/s times the nominal one
            return a_s, g, (gain_s - g * gain_a) * datum

        return arx_scan(a, b, u, noise, y_forced, lambda u_t, y_t, lags: (u_t, 0.0 * y_t),
                        varying=law)

    @classmethod
    def start(cls, ctx):
        """Exponents from none (the nominal model, so the fit never starts worse than the
        refit) through mild to Torricelli's, each with outlets at a few depths below the
        lowest level; the diagnosis starts from the one with the lowest criterion. A
        plant whose level swings over a small part of its depth (a deep outlet) shows
        only a mild scaling over the record, which Torricelli's exponent with a shallow
        outlet overstates: on such records every start at alpha = 1/2 simulated far worse
        than the nominal model and the fit stayed there."""
        y = ctx.y_fit
        mean, std = float(np.mean(y)), max(float(np.std(y)), 1e-12)
        low = mean - float(np.min(y))
        depths = [np.log(max(f * low, 0.05 * std) / std) for f in (1.05, 1.5, 3.0, 10.0)]
        origin = -mean / std  # the measured output's zero, in the datum's units
        return np.array([[alpha, d, datum] for alpha in (0.0, 0.1, 0.25, 0.5) for d in depths
                         for datum in (-np.exp(d), origin)])

    @classmethod
    def scales(cls, ctx):
        return np.array([0.2, 0.5, 0.5])

    def describe(self, ctx, info):
        y = np.asarray(info["y"])
        alpha, outlet = float(self.alpha), float(self.outlet)
        lo, hi = (float(q) for q in np.quantile(y, [0.1, 0.9]))
        s_lo, s_hi = float(self.scaling(lo)), float(self.scaling(hi))
        ratio = s_lo / s_hi if s_hi > 0 else np.inf
        law = ("Torricelli's law (exponent 1/2)" if abs(1 - alpha - 0.5) <= 0.15 else
               f"not Torricelli's 1/2: fitted exponent {rounded(1 - alpha, 3)}")
        trend = "grow" if ratio > 1 else "shrink"
        return {
            "physics": (f"The dynamics depend on the output level: the outflow goes as "
                        f"(level - {rounded(outlet, 3)})^{rounded(1 - alpha, 3)} ({law}), "
                        f"so the time constant and the gain {trend} with the level, by a "
                        f"factor {rounded(ratio, 3)} from level {rounded(lo, 3)} to "
                        f"{rounded(hi, 3)}: a tank drained through an orifice."),
            "where": {"windows": [[0, len(y)]], "output_range": [lo, hi],
                      "regime": "output level"},
            "parameters": {"outflow_exponent": rounded(1 - alpha), "alpha": rounded(alpha),
                           "outlet_level": rounded(outlet),
                           "datum_level": rounded(float(self.datum_level)),
                           "time_constant_ratio": rounded(ratio)},
        }

    @classmethod
    def concealed(cls, base, signals, rng):
        y0 = signals["y0"]
        mean, std = float(np.mean(y0)), max(float(np.std(y0)), 1e-12)
        depth = 1.2 * (mean - float(np.min(y0))) + 0.1 * std
        model = cls(base, jnp.asarray(0.5), jnp.asarray(np.log(depth / std)),
                    jnp.asarray(mean), jnp.asarray(std))
        return model, base, {"alpha": 0.5, "outlet": mean - depth}


# Both maps give the coefficients of A_s as scalars, evaluated inside the scan's step by
# scalar arithmetic: XLA fuses it into the step's one kernel, where small dots, stacks and
# pows each cost a kernel (an array form of the step ran 1.7x slower).

def _matched_scaling(a):
    """``s -> [a_1(s), ..., a_na(s)]``, the coefficients of ``A_s`` with every pole ``p``
    of ``A`` moved to ``p^s`` (``-|p|^s`` for a negative real pole). The poles are found
    once per record (:func:`_pole_rates`)."""
    na = a.shape[0]
    log_mag, angle, negative = _pole_rates(a)

    def scaled(s):
        coef_re, coef_im = [jnp.ones_like(s)], [jnp.zeros_like(s)]
        for i in range(na):
            mag = jnp.exp(s * log_mag[i])
            q_re = jnp.where(negative[i], -mag, mag * jnp.cos(s * angle[i]))
            q_im = jnp.where(negative[i], 0.0, mag * jnp.sin(s * angle[i]))
            # the polynomial times (1 - q z^-1)
            nxt_re, nxt_im = list(coef_re) + [0.0], list(coef_im) + [0.0]
            for k in range(1, i + 2):
                nxt_re[k] = nxt_re[k] - (q_re * coef_re[k - 1] - q_im * coef_im[k - 1])
                nxt_im[k] = nxt_im[k] - (q_re * coef_im[k - 1] + q_im * coef_re[k - 1])
            coef_re, coef_im = nxt_re, nxt_im
        return coef_re[1:]  # conjugate pairs: the imaginary parts cancel

    return scaled


def _bilinear_scaling(a):
    """``s -> [a_1(s), ..., a_na(s)]`` with every pole ``p`` moved to
    ``(1 + s x) / (1 - s x)``, ``x = (p - 1) / (p + 1)``: the law's map before the matched
    one, kept so that model files written with it simulate as they did. The coefficients
    of ``A_s`` are polynomials in ``s`` (:func:`_rate_maps`), evaluated with powers of
    ``s`` by products."""
    na = a.shape[0]
    to_rates, from_rates = (jnp.asarray(m, a.dtype) for m in _rate_maps(na))
    rates = to_rates @ jnp.concatenate([jnp.ones(1, a.dtype), a])
    table = (from_rates * rates[None, :])[:, ::-1]   # columns: s^0 .. s^na
    rows = [[table[i, k] for k in range(na + 1)] for i in range(na + 1)]

    def scaled(s):
        powers = [jnp.ones_like(s)]
        for _ in range(na):
            powers.append(powers[-1] * s)

        def poly(coefs):
            return sum(c * p for c, p in zip(coefs, powers))

        inv_lead = 1.0 / poly(rows[0])
        return [poly(rows[i + 1]) * inv_lead for i in range(na)]

    return scaled


def _pole_rates(a):
    """``(log|p|, angle, negative)`` of the poles ``p`` of ``A`` (roots of
    ``z^na + a_1 z^(na-1) + ... + a_na``), each an ``na`` vector: ``p^s`` is then
    ``exp(s log|p|) (cos(s angle) + i sin(s angle))``, the pole whose continuous-time rate
    ``log p`` is ``s`` times as large, or ``-|p|^s`` where ``negative`` (a negative real
    pole has no continuous-time rate; it keeps its sign). The eigenvalues' derivatives are
    those of the companion matrix (``jax.numpy.linalg.eigvals``); a zero pole stays at 0."""
    na = a.shape[0]
    if na == 0:
        empty = jnp.zeros((0,), a.dtype)
        return empty, empty, jnp.zeros((0,), bool)
    companion = jnp.zeros((na, na), a.dtype).at[0].set(-a)
    if na > 1:
        companion = companion.at[jnp.arange(1, na), jnp.arange(na - 1)].set(1.0)
    p = jnp.linalg.eigvals(companion)
    re, im = jnp.real(p), jnp.imag(p)
    negative = (im == 0) & (re < 0)
    mag2 = re * re + im * im
    zero = mag2 == 0
    # guarded so that a zero pole (a_na = 0) has finite derivatives: exp(s * -690) = 0
    log_mag = jnp.where(zero, -690.0, 0.5 * jnp.log(jnp.where(zero, 1.0, mag2)))
    angle = jnp.where(zero | negative, 0.0,
                      jnp.arctan2(im, jnp.where(zero, 1.0, re)))
    return log_mag, angle, negative


@functools.cache
def _rate_maps(na):
    """Linear maps between the coefficients of ``A`` (``[1, a_1, ..., a_na]``, powers of
    ``z`` from ``z^na`` down) and those of ``(1 - x)^na A((1 + x) / (1 - x))`` (powers
    ``x^0 .. x^na``, ``x = (z - 1) / (z + 1)``), in which multiplying every root by ``s``
    multiplies the coefficient of ``x^i`` by ``s^(na - i)``."""
    P = np.polynomial.polynomial
    to_rates = np.zeros((na + 1, na + 1))
    from_rates = np.zeros((na + 1, na + 1))
    for k in range(na + 1):
        c = P.polymul(P.polypow([1.0, 1.0], na - k), P.polypow([1.0, -1.0], k))
        to_rates[: len(c), k] = c
    for i in range(na + 1):
        c = P.polymul(P.polypow([-1.0, 1.0], i), P.polypow([1.0, 1.0], na - i))
        from_rates[:, i] = np.pad(c, (0, na + 1 - len(c)))[::-1]  # row k: z^(na - k)
    return to_rates, from_rates
