"""Level-dependent dynamics with an unmeasured upstream level: the measured output is the
level of a store fed through a second store, each drained through an outlet (Torricelli's
outflow ~ sqrt(level)), the upstream one overflowing at a level.

This is the level law of a cascade of tanks, which :class:`hbjax._diagnose.effects.
LevelDependentDynamics` cannot express: that law scales the nominal linear block with the
*measured* level, so it has no second level of its own, while in a cascade the upstream
level sets the inflow of the measured one and, where it overflows, caps it. The model
replaces the linear block (its two levels are its state); its inflow is affine in the
recorded input or in the nominal model's internal signal ``u`` (eq. (10)), whichever fits
better. It is tried where the nominal free run's error depends on the output level (the
regime test), fitted by output error under either criterion, and reported only on held-out
evidence (see :func:`level_cascade_on_nominal`)."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float

from .._core.buckets import bucket_length, padded
from .._core.initial import InitialState
from .._core.model import AbstractModel, Hammerstein, play_trajectory
from .._core.simulate import play, simulate
from .._misc import jsonable as _jsonable
from . import residual_tests as rt
from .decide import BIC_MARGIN, DM_Z, over_constant
from .effect_base import EffectConstraint
from .explain import rounded
from .result import Finding

#: key of the candidate table for the two-level cascade
ON_NOMINAL = "level_dependent_dynamics (two levels in series, overflow)"
#: the share of the nominal free-run error's variance the output level must explain
#: (:func:`hbjax._diagnose.residual_tests.regime_dependence`) before the cascade is tried
MIN_LEVEL_SHARE = 0.10
#: the share below which a mechanism already found has taken the level dependence out of
#: the free-run error (measured: a clip leaves about 1 %; the tanks' nominal error, 24 %
#: by the level, keeps 8 % after `unmodeled_dynamics`), so the cascade is not tried
LEFT_LEVEL_SHARE = 0.05
#: random starts per feed (the recorded input, the nominal internal signal), screened by
#: their free-run error; the best KEEP of each are solved, with at most MAX_STEPS steps
STARTS = 64
KEEP = 6
MAX_STEPS = 200
#: parameters: inflow gain and offset, upstream outflow and outlet, the share of that
#: outflow the measured store receives, the measured store's outflow and outlet, the
#: upstream overflow level and the share of the overflow it receives; and the two
#: initial levels
N_PARAMS = 11
FEEDS = ("input", "internal")
#: the factor by which a store's time constant must change between the 10th and 90th
#: percentiles of its levels over the record (:func:`time_constants`) for the law to be
#: named: with both outlets far below the levels the stores hold, Torricelli's outflows
#: are linear there and the cascade is a linear block in disguise. Measured: at most 1.10
#: (the larger of the two stores' factors) where it outranked a sensor clip or an
#: unmodelled lag on a linear plant (three generator records); 1.37 and 2.0 on two
#: records of tests/generators/two_tanks.py, 5.5 on the Cascaded Tanks
#: (benchmarks/RESULTS.md)
MIN_TIME_CONSTANT_RATIO = 1.2


def _flow(level):
    """Torricelli's outflow through an outlet at 0: ``sqrt(max(level, 0))``; the small
    floor keeps its derivative finite where a store runs dry."""
    return jnp.sqrt(jnp.maximum(level, 0.0) + 1e-12)


def _levels(p, x0, w, noise):
    """Both levels over a record, in the units the fit works in (the measured level
    centred and scaled by the record's spread, the feed by its largest magnitude):

        ``x1(t+1) = min(x1(t) + g w(t) + c - k1 q(x1(t) - o1), h)``
        ``x2(t+1) = x2(t) + k2 q(x1(t) - o1) + r s(t) - k3 q(x2(t) - o2) + noise(t)``

    with ``q`` Torricelli's outflow and ``s(t)`` the overflow (the excess over ``h``).
    Returns ``(x2, s)``."""
    k3, o2 = p[5], p[6]

    def step(x, inputs):
        x1, x2 = x
        w_t, xi_t = inputs
        x1_next, inflow, spill = _upper_step(p, x1, w_t)
        return (x1_next, x2 + inflow - k3 * _flow(x2 - o2) + xi_t), (x2, spill)

    return jax.lax.scan(step, (x0[0], x0[1]), (w, noise))[1]


def _upper_step(p, x1, w_t):
    """The upper store over one sample: ``(x1(t+1), inflow of the measured store,
    overflow)`` (the equations of :func:`_levels`)."""
    g, c, k1, o1, k2, _, _, h, r = (p[i] for i in range(9))
    out1 = _flow(x1 - o1)
    filled = x1 + g * w_t + c - k1 * out1
    spill = jnp.maximum(filled - h, 0.0)
    return filled - spill, k2 * out1 + r * spill, spill


class LevelCascade(AbstractModel):
    """The measured output ``y`` as the lower of two stores in series (see
    :func:`_levels` for the equations), read through the sensor's range ``[lower,
    upper]`` where the record shows it (``None``: open). ``feed``: ``"input"`` (the
    inflow is affine in the recorded input) or ``"internal"`` (in the base model's play
    operator output ``u``). ``params`` and ``levels0`` (the upstream and measured levels
    at the record's first sample) are in the fit's units: levels as ``(y - y_center) /
    y_scale``, the feed divided by ``w_scale``."""

    base: Hammerstein
    params: Float[Array, " 9"]
    levels0: Float[Array, " 2"]
    w_scale: float
    y_center: float
    y_scale: float
    lower: float | None = None
    upper: float | None = None
    feed: str = eqx.field(static=True, default="input")

    def __check_init__(self):
        # Held to the effects' rules (the model-file reader runs this too): a file with
        # text, a list or NaN in a field is refused here, naming the field.
        if self.feed not in FEEDS:
            raise ValueError(f"`LevelCascade.feed` must be one of {FEEDS}, got {self.feed!r}.")
        if not isinstance(self.base, Hammerstein):
            raise TypeError("`LevelCascade.base` must be an hbjax.Hammerstein, got "
                            f"{type(self.base).__name__}.")
        rules = {"params": EffectConstraint(shape=(9,)),
                 "levels0": EffectConstraint(shape=(2,)),
                 "w_scale": EffectConstraint(positive=True),
                 "y_scale": EffectConstraint(positive=True),
                 "y_center": EffectConstraint(),
                 "lower": EffectConstraint(optional=True),
                 "upper": EffectConstraint(optional=True)}
        values = {field: rule.check(f"LevelCascade.{field}", getattr(self, field), self.base)
                  for field, rule in rules.items()}
        lower, upper = values["lower"], values["upper"]
        if lower is not None and upper is not None and not lower < upper:
            raise ValueError("the sensor's range needs `LevelCascade.lower` < "
                             f"`LevelCascade.upper`, got {lower.item()} and {upper.item()}.")

    def _feed(self, v, u0):
        w = v if self.feed == "input" else play_trajectory(self.base.backlash, v, u0)
        return w / self.w_scale

    def _read(self, x2):
        y = self.y_center + self.y_scale * x2
        if self.lower is not None or self.upper is not None:
            y = jnp.clip(y, self.lower, self.upper)
        return y

    def simulate_trajectory(self, v, noise, u0):
        x2, _ = _levels(self.params, self.levels0, self._feed(v, u0), noise / self.y_scale)
        return self._read(x2)

    def predict_trajectory(self, v, y, u0):
        # the upstream level runs free (it is not measured); the measured one is the
        # recorded output one sample back
        k3, o2 = self.params[5], self.params[6]
        w = self._feed(v, u0)
        x2m = (y - self.y_center) / self.y_scale

        def step(x1, w_t):
            x1_next, inflow, _ = _upper_step(self.params, x1, w_t)
            return x1_next, inflow

        _, inflow = jax.lax.scan(step, self.levels0[0], w)
        prev = jnp.concatenate([self.levels0[1:], x2m[:-1]])
        return self._read(prev + jnp.concatenate([jnp.zeros(1, w.dtype), inflow[:-1]])
                          - k3 * _flow(prev - o2) * (jnp.arange(w.shape[0]) > 0))

    def estimate_start(self, v, y):
        """``(InitialState, y_hat)``: the two levels at the record's first sample fitted to
        ``y`` by least squares of the free run (``hbjax.compare``'s
        ``initial_state="estimate"``); ``InitialState.y0`` holds them in the output's
        units, ``[measured, upstream]``."""
        v, y = jnp.asarray(v), jnp.asarray(y)
        target0 = float((y[0] - self.y_center) / self.y_scale)
        x0s = jnp.asarray([[up, target0] for up in (-1.0, 0.0, 1.0, 2.0, float(self.levels0[0]))])
        fitted, costs = (np.asarray(a) for a in _start_levels(self, v, y, x0s))
        costs = np.where(np.isfinite(costs), costs, np.inf)
        i = int(np.argmin(costs))
        # where no start gives a finite free run, the levels the model was fitted with stand
        cost, x0 = ((float(costs[i]), jnp.asarray(fitted[i])) if np.isfinite(costs[i])
                    else (math.inf, self.levels0))
        fitted = eqx.tree_at(lambda m: m.levels0, self, x0)
        y_hat = fitted.simulate_trajectory(v, jnp.zeros_like(v), 0.0)
        state = InitialState(self.y_center + self.y_scale * x0[::-1], jnp.zeros(()),
                             jnp.asarray(cost))
        return state, y_hat


@eqx.filter_jit
def _start_levels(model, v, y, x0s):
    """The two starting levels fitted to ``y`` from every row of ``x0s`` (one batched
    solve, compiled once per record length): ``(levels, costs)``."""
    w = model._feed(v, 0.0)

    def resid(x0, _):
        return model._read(_levels(model.params, x0, w, jnp.zeros_like(w))[0]) - y

    def one(x0):
        x = optx.least_squares(resid, optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8), x0,
                               max_steps=300, throw=False).value
        return x, jnp.sum(resid(x, None) ** 2)

    return jax.vmap(one)(x0s)


def _starts(rng, y0, n):
    """Random starts in the fit's units: slow stores (rates 10^-2 .. 10^-0.5 per sample,
    inflow gains up to 1) with outlets below the lowest level and an overflow level
    above the upstream store's starting level."""
    rows = []
    for _ in range(n):
        k1, k2, k3 = 10 ** rng.uniform(-2.0, -0.5, 3)
        g = 10 ** rng.uniform(-2.5, 0.0)
        up = y0 + rng.uniform(0.0, 1.5)
        rows.append([g, -g * rng.uniform(0.0, 1.0), k1, rng.uniform(-3.0, 0.0), k2, k3,
                     y0 - rng.uniform(1.0, 4.0), up + rng.uniform(0.2, 4.0),
                     rng.uniform(0.0, 1.5), up, y0])
    return np.asarray(rows)


def _free_run_error(z, w, target, lo, hi):
    x2 = _levels(z[:9], z[9:], w, jnp.zeros_like(w))[0]
    return jnp.clip(x2, lo, hi) - target


@jax.jit
def _screen(z0, feed_index, feeds, target, lo, hi):
    """Sum of squared free-run errors of every start (one batched run)."""
    return jax.vmap(lambda z, k: jnp.sum(_free_run_error(z, feeds[k], target, lo, hi) ** 2))(
        z0, feed_index)


@jax.jit
def _solve(z0, feed_index, feeds, target, lo, hi):
    """Output-error Levenberg-Marquardt fits from the starts (one batched solve; compiled
    once per record length)."""

    def one(z, k):
        return optx.least_squares(
            lambda z, _: _free_run_error(z, feeds[k], target, lo, hi),
            optx.LevenbergMarquardt(rtol=1e-7, atol=1e-7), z, max_steps=MAX_STEPS,
            throw=False).value

    return jax.vmap(one)(z0, feed_index)


@jax.jit
def _runs(z, feed_index, feeds):
    """The measured level's free run (fit units) for every fitted vector."""
    return jax.vmap(lambda z, k: _levels(z[:9], z[9:], feeds[k], jnp.zeros_like(feeds[k]))[0])(
        z, feed_index)


def _fit(feeds, target, clip, z0, feed_index):
    """The fitted vectors from the ``KEEP`` best starts per feed of ``z0`` (start ``i``
    with feed ``feeds[feed_index[i]]``): the random starts are screened by their free-run
    error in one batched run, and only the best are solved, since a batched solve runs
    as long as its slowest member. Returns ``(z, feed_index)``."""
    feeds, target = jnp.asarray(feeds), jnp.asarray(target)
    lo, hi = (jnp.asarray(c, target.dtype) for c in clip)
    cost = np.asarray(_screen(jnp.asarray(z0), jnp.asarray(feed_index), feeds, target, lo, hi))
    cost = np.where(np.isfinite(cost), cost, np.inf)
    keep = np.concatenate([np.flatnonzero(feed_index == k)[np.argsort(cost[feed_index == k])][:KEEP]
                           for k in np.unique(feed_index)])
    z = _solve(jnp.asarray(z0[keep]), jnp.asarray(feed_index[keep]), feeds, target, lo, hi)
    return np.asarray(z), feed_index[keep]


def level_share_left(found, v, y, n_fit, burn, tests) -> float:
    """The share of the free-run error's variance on the fitting segment that the output
    level explains (:func:`hbjax._diagnose.residual_tests.regime_dependence`), left by the
    best mechanism ``found`` so far, or by the nominal model where there is none: a level
    law is not needed where a mechanism already found (a sensor's clip, a curved sensor)
    took the level dependence out of the error."""
    nominal = float(tests.get("regime_output", {}).get("explained", 0.0))
    if found is None:
        return nominal
    y_f = np.asarray(simulate(found.model, v))[burn:n_fit]
    r = np.asarray(y)[burn:n_fit] - y_f
    if not np.all(np.isfinite(r)):
        return nominal
    return float(rt.regime_dependence(r, y_f)["explained"])


def level_cascade_on_nominal(model, y, v, n_fit, burn, ysim_all, u_all, stats, names, tests,
                             sensor, found=None):
    """The two-level cascade fitted by output error on the fitting segment, tried (by
    :func:`hbjax.diagnose`, either criterion) where the output level explains
    at least MIN_LEVEL_SHARE of the nominal free-run error's variance, and, where a
    mechanism was ``found`` already, at least LEFT_LEVEL_SHARE of the error the best one
    leaves (:func:`level_share_left`). ``sensor``: the record's plateau signatures
    (:func:`hbjax._diagnose.residual_tests.plateaus`, ``(lower, upper)``, ``None`` for a
    side without one): the sensor's range the model reads its level through.

    Decision (all required): BIC gain of its free run over the nominal model's > BIC_MARGIN
    on the fitting segment (after the burn-in, ``N_PARAMS`` parameters, and the nominal
    backlash's ``2 m`` for the internal feed; the feed and the start by the same BIC); on the held-out
    part, a significantly smaller free-run error than the refit's and a constant output's
    (Diebold-Mariano z > DM_Z against each), and a higher fit than the nominal model's;
    and a law that depends on the level where the record is: a store's time constant
    changes by MIN_TIME_CONSTANT_RATIO or more over its levels (:func:`time_constants`).
    Against the nominal model the gain need not be significant: a nominal model fitted on
    the record being diagnosed (the plain path) saw the held-out part, which biases any test
    there toward it, while the refit, like this model, saw only the fitting segment. Its
    BIC is on the output error (``evidence["bic_criterion"]``), so under the prediction
    criterion it is placed among the other findings by the held-out free run
    (:func:`hbjax._diagnose.decide.place_by_free_run`). The model's sensor
    range reproduces the record's plateaus, so a clip found beside it does not outrank it
    (``evidence["record_signature"]``, :func:`hbjax._diagnose.decide.rank`).

    Returns ``(table_row | None, Finding | None)``."""
    if float(tests.get("regime_output", {}).get("explained", 0.0)) < MIN_LEVEL_SHARE:
        return None, None  # before simulating the mechanism found (a compilation per kind)
    share = level_share_left(found, v, y, n_fit, burn, tests)
    if found is not None and share < LEFT_LEVEL_SHARE:
        return {"level_share": share, "decision": f"not tried: the output level explains "
                f"{share:.0%} of the free-run error {found.effect} leaves"}, None
    y = np.asarray(y, float)
    # its levels start where it fits them, but the nominal free run starts from rest
    burn = max(burn, min(n_fit // 5, 300))
    clip = tuple(None if sig is None else sig["level"] for sig in sensor)
    sensor_signature = {side: sig for side, sig in zip(("lower", "upper"), sensor)
                        if sig is not None} or None
    center, scale = float(np.mean(y[:n_fit])), max(float(np.std(y[:n_fit])), 1e-12)
    target = (y - center) / scale
    u = np.asarray(u_all[0])
    scales = [max(float(np.max(np.abs(x[:n_fit]))), 1e-12) for x in (v, u)]
    feeds = np.stack([v / scales[0], u / scales[1]])
    lo = -np.inf if clip[0] is None else (clip[0] - center) / scale
    hi = np.inf if clip[1] is None else (clip[1] - center) / scale
    rng = np.random.default_rng(0)
    z0 = np.concatenate([_starts(rng, float(target[0]), STARTS) for _ in FEEDS])
    which = np.repeat(np.arange(len(FEEDS)), STARTS)
    z, which = _fit(feeds[:, :n_fit], target[:n_fit], (lo, hi), z0, which)

    # every fitted start run over the whole record (the fitting part decides)
    y_runs = center + scale * np.clip(np.asarray(_runs(jnp.asarray(z), jnp.asarray(which),
                                                       jnp.asarray(feeds))), lo, hi)
    sse_fit = np.sum((y[burn:n_fit] - y_runs[:, burn:n_fit]) ** 2, axis=1)
    sse_fit = np.where(np.isfinite(sse_fit), sse_fit, np.inf)
    n = n_fit - burn
    # the internal signal carries the nominal backlash's 2m fitted parameters
    k_feed = N_PARAMS + 2 * model.backlash.m * which
    bics = n * np.log(np.maximum(sse_fit, 1e-300) / n) + k_feed * math.log(n)
    best = int(np.argmin(bics))
    if not np.isfinite(sse_fit[best]):
        return {"bic": np.inf, "fit_sim": np.nan,
                "decision": "failed: no start gave a finite free run"}, None
    zb, kb, k = z[best], int(which[best]), int(k_feed[best])
    y_c = y_runs[best]
    y_nom = np.asarray(ysim_all[0])
    sse_nom = float(np.sum((y - y_nom)[burn:n_fit] ** 2))
    dbic = n * math.log(max(sse_nom, 1e-300) / max(sse_fit[best], 1e-300)) - k * math.log(n)
    ref_i = names.index("parameter_mismatch") + 1
    # the refit's BIC on the same footing: its free run on the same window (the candidate
    # table's BIC of the refit is on the diagnosis' criterion, one-step prediction by default)
    sse_ref = float(np.sum((y - np.asarray(ysim_all[ref_i]))[burn:n_fit] ** 2))
    dbic_ref = (n * math.log(max(sse_ref, 1e-300) / max(sse_fit[best], 1e-300))
                - (k - stats[ref_i]["k"]) * math.log(n)) if math.isfinite(sse_ref) else math.inf
    r_c, r_nom = (y - y_c)[n_fit:], (y - y_nom)[n_fit:]
    r_ref = (y - np.asarray(ysim_all[ref_i]))[n_fit:]
    fit_c = rt.fit_percent_unchecked(y[n_fit:], y_c[n_fit:])
    fit_nom = rt.fit_percent_unchecked(y[n_fit:], y_nom[n_fit:])
    dm_nom = rt.diebold_mariano(r_nom, r_c)
    # a refit whose free run diverged is no rival (its candidate is listed as failed)
    dm_ref = rt.diebold_mariano(r_ref, r_c) if np.all(np.isfinite(r_ref)) else np.inf
    dm_const = over_constant(y, n_fit, burn, r_c)
    bic = float(bics[best])
    row = {"bic": bic, "k": k, "level_share": share, "feed": FEEDS[kb],
           "dbic": dbic, "fit_sim": fit_c, "dm_z": dm_nom, "dm_z_vs_refit": dm_ref,
           "dm_z_over_constant": dm_const}
    why = None
    if not dbic > BIC_MARGIN:
        why = "BIC gain over the nominal free run not above the margin"
    elif not fit_c > fit_nom:
        why = "held-out free run not better than the nominal model's"
    elif not dm_ref > DM_Z:
        why = "held-out free run not significantly better than the refit's"
    elif not dm_const > DM_Z:
        why = "held-out free run not significantly better than a constant output"
    ext = LevelCascade(model, jnp.asarray(zb[:9]), jnp.asarray(zb[9:]), scales[kb], center,
                       scale, clip[0], clip[1], FEEDS[kb])
    taus = time_constants(ext, v, y)
    row["time_constant_samples"] = taus
    if why is None and not any(max(t) >= MIN_TIME_CONSTANT_RATIO * min(t)
                               for t in taus.values()):
        why = ("no level dependence: over the levels the record holds, the fitted law's "
               "time constants change only from {:.3g} to {:.3g} samples (measured store) "
               "and from {:.3g} to {:.3g} (upstream store): linearised stores".format(
                   *taus["measured"], *taus["upstream"]))
    row["decision"] = why or "reported"
    if why is not None:
        return row, None
    text = _describe(ext, v, y, taus)
    evidence = {
        "variant": "two levels in series with Torricelli outflows and an upstream overflow, "
                   "fitted by output error (the nominal linear block replaced)",
        "reference": "nominal", "base": "replaced", "feed": FEEDS[kb], "bic": bic,
        "bic_criterion": "simulation",
        "delta_bic_vs_nominal": dbic, "delta_bic_vs_refit": dbic_ref,
        "dm_z": dm_nom, "dm_z_vs_refit": dm_ref, "dm_z_over_constant": dm_const,
        "reference_fit": fit_nom, "refit_fit": rt.fit_percent_unchecked(
            y[n_fit:], np.asarray(ysim_all[ref_i])[n_fit:]),
        "parameters_fitted": k, "level_share": share, "kind": "mechanism",
        "record_signature": sensor_signature,
    }
    return row, Finding(
        effect="level_dependent_dynamics", physics=text["physics"],
        where=_jsonable(text["where"]), parameters=_jsonable(text["parameters"]), model=ext,
        metric="simulation", fit_before=fit_nom, fit_after=fit_c, evidence=_jsonable(evidence))


@jax.jit
def _upstream_run(p, x0, w):
    def step(x1, w_t):
        return _upper_step(p, x1, w_t)[0], x1

    return jax.lax.scan(step, x0, w)[1]


def _upstream_levels(ext, v):
    """The upstream store's level over the record (fit units; :func:`_levels`), run on
    the record padded to its length's bucket (one compiled program for many lengths; the
    recursion is causal, so the padding cannot change the first samples)."""
    v = np.asarray(v, float)
    w = (v if ext.feed == "input" else np.asarray(play(ext.base.backlash, v))) / ext.w_scale
    n = len(w)
    x1 = _upstream_run(ext.params, ext.levels0[0], padded(w, bucket_length(n)))
    return np.asarray(x1)[:n]


def time_constants(ext, v, y):
    """Each store's local time constant (samples) at the 10th and 90th percentiles of its
    level over the record: the inverse slope of its outflow, ``d(k q(x - o))/dx = k / (2
    sqrt(x - o))`` (Torricelli), at the recorded level ``y`` for the measured store and at
    the simulated one (input ``v``) for the upstream store. Returns ``{"measured": (lo,
    hi), "upstream": (lo, hi)}``."""
    p = [float(x) for x in ext.params]

    def tau(levels, k, outlet):
        return tuple(2.0 * math.sqrt(max(float(q) - outlet, 1e-12)) / max(k, 1e-12)
                     for q in np.quantile(levels, [0.1, 0.9]))

    measured = (np.asarray(y, float) - ext.y_center) / ext.y_scale
    return {"measured": tau(measured, p[5], p[6]),
            "upstream": tau(_upstream_levels(ext, v), p[2], p[3])}


def _describe(ext, v, y, taus):
    """The physics sentence and parameter table from the fitted values and the stores'
    time constants (:func:`time_constants`, computed once by the decision)."""
    g, _, k1, _, k2, k3, o2, _, r = (float(x) for x in ext.params)
    w = np.asarray(ext._feed(jnp.asarray(v), 0.0))
    _, spill = _levels(ext.params, ext.levels0, jnp.asarray(w), jnp.zeros(len(w)))
    overflowing = int(np.sum(np.asarray(spill) > 0))
    outlet = ext.y_center + ext.y_scale * o2
    lo, hi = (float(q) for q in np.quantile(y, [0.1, 0.9]))
    tau = taus["measured"]
    feed = ("the recorded input" if ext.feed == "input" else
            "the nominal model's internal signal u")
    text = (f"The output is the level of a store fed through a second, unmeasured store: the "
            f"inflow, affine in {feed}, fills the upstream store, which drains into the "
            f"measured one, and each drains through an outlet as the square root of its "
            f"level (Torricelli); the measured store's outlet sits at {rounded(outlet, 3)}, so "
            f"its time constant grows from {rounded(tau[0], 3)} to {rounded(tau[1], 3)} "
            f"samples between levels {rounded(lo, 3)} and {rounded(hi, 3)}, and the "
            f"upstream store's from {rounded(taus['upstream'][0], 3)} to "
            f"{rounded(taus['upstream'][1], 3)} samples over the levels it holds.")
    if overflowing:
        text += (f" The upstream store overflows on {overflowing} samples of the record "
                 f"(a share {rounded(r, 3)} of the overflow reaches the measured store).")
    else:
        text += " The upstream store never overflows on this record."
    if ext.upper is not None or ext.lower is not None:
        limits = " and ".join(f"{word} {level}" for word, level in
                              (("at least", ext.lower), ("at most", ext.upper)) if level is not None)
        text += (f" The sensor reads {limits} (the record holds its output exactly there).")
    return {
        "physics": text,
        "where": {"windows": [[0, len(y)]], "output_range": [lo, hi], "regime": "output level"},
        "parameters": {"feed": ext.feed, "outlet_level": rounded(outlet),
                       "time_constant_samples": [rounded(t) for t in tau],
                       "upstream_time_constant_samples": [rounded(t)
                                                          for t in taus["upstream"]],
                       "overflow_samples": overflowing, "overflow_share": rounded(r),
                       "sensor_range": [ext.lower, ext.upper],
                       "inflow_gain": rounded(g), "upstream_rate": rounded(k1),
                       "transfer_rate": rounded(k2), "outflow_rate": rounded(k3)},
    }
