"""Dynamics whose gain and time constant change with the output level (a tank drained
through an orifice: Torricelli's outflow ~ sqrt(level))."""

from __future__ import annotations

import functools
from typing import ClassVar

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
    ``s`` (through the bilinear map ``x = (z - 1) / (z + 1)``: pole ``p`` goes to
    ``(1 + s x_p) / (1 - s x_p)``, stable for every ``s > 0``) and ``g = A_s(1) / (s A(1))``
    sets the static gain to ``1/s`` times the nominal one. In equilibrium
    ``s A(1) (y - outlet) = B(1) u - A(1) outlet``: the outflow goes as
    ``(y - outlet)^(1 - alpha)``, Torricelli's law for ``alpha = 1/2``; locally every time
    constant and the gain grow as ``(y - outlet)^alpha``. ``s = 1`` at the mean level, so
    ``alpha = 0`` is the nominal model. Fitted: ``alpha``, ``log_depth``
    (``depth = exp(log_depth) y_std``) and the ``datum`` (below; ``None``: the outlet).

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

    name: ClassVar[str] = "level_dependent_dynamics"
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
    # "the level law's anchored variant, before and after"). Where a strong
    # law's record rejects the held base (the bilinear pole map is not the plant's), the
    # base-consistency test refuses the anchored variant and the joint one stands.

    @classmethod
    def from_params(cls, base, params, consts=None):
        mean, std = (0.0, 1.0) if consts is None else (consts[1], consts[2])
        mean, std = jnp.asarray(mean), jnp.asarray(std)
        # the datum in units of the output's spread from its mean, as the depth
        return cls(base, params[0], params[1], mean, std, mean + params[2] * std)

    def params(self):
        return jnp.stack([jnp.asarray(self.alpha), jnp.asarray(self.log_depth),
                          (self.datum_level - self.y_mean) / self.y_std])

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
        na = a.shape[0]
        to_rates, from_rates = (jnp.asarray(m, a.dtype) for m in _rate_maps(na))
        rates = to_rates @ jnp.concatenate([jnp.ones(1, a.dtype), a])
        # the coefficients of A_s are polynomials in s: A_s = scaled @ [1, s, ..., s^na]
        # with one matrix for the whole record. Inside the step they are evaluated on
        # scalars with powers of s by products: XLA fuses scalar arithmetic into the
        # step's one kernel, while small dots, stacks and pows each cost a kernel (the
        # array form of this step ran 1.7x slower)
        scaled = (from_rates * rates[None, :])[:, ::-1]   # columns: s^0 .. s^na
        total = jnp.sum(scaled, axis=0)
        rows = [[scaled[i, k] for k in range(na + 1)] for i in range(na + 1)]
        total = [total[k] for k in range(na + 1)]
        gain_a = 1.0 + jnp.sum(a)
        datum = self.datum_level

        def law(level):
            s = self.scaling(level)
            s_pows = [jnp.ones_like(s)]
            for _ in range(na):
                s_pows.append(s_pows[-1] * s)

            def poly(coefs):
                return sum(c * p for c, p in zip(coefs, s_pows))

            inv_lead = 1.0 / poly(rows[0])
            a_s = [poly(rows[i + 1]) * inv_lead for i in range(na)]
            gain_s = poly(total) * inv_lead   # A_s(1)
            g = gain_s / (s * gain_a)         # static gain 1/s times the nominal one
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
