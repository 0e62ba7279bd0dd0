"""Physics inside the dynamics: dry friction opposing the output's own motion, level-
dependent (Torricelli) dynamics and input-driven harmonic distortion, each checked against
a plain NumPy loop and named by the diagnosis on recordings of the independent generator
(tests/generators/concealed_effects.py) over a few random seeds."""

import jax.numpy as jnp
import numpy as np
import pytest
from generators.concealed_effects import concealed_case

import hbjax


def _system():
    return hbjax.Hammerstein(hbjax.Backlash(c1=[-0.3, 1.0], c2=[0.3, 1.0]),
                             hbjax.ARX(a=[-0.8], b=[0.2]))


def _loop(v, c1, c2, a, b, law, measured=None):
    """Free run, or with ``measured`` the one-step prediction (the measured output in
    the lag and in the law)."""
    u, y, s = np.zeros(len(v)), np.zeros(len(v)), 0.0
    for t in range(len(v)):
        s = min(max(s, c1[0] + c1[1] * v[t]), c2[0] + c2[1] * v[t])
        u[t] = s
    w_prev, extra = 0.0, 0.0
    y_prev = 0.0
    for t in range(len(v)):
        y[t] = -a * y_prev + b * w_prev + extra
        y_t = y[t] if measured is None else measured[t]
        w_prev, extra = law(u[t], y_t)
        y_prev = y_t
    return y


def test_friction_in_loop_matches_plain_loop():
    model = _system()
    v = np.repeat(np.random.default_rng(0).uniform(-3, 3, 30), 10)
    fx = hbjax.EFFECTS["coulomb_friction"](model, jnp.asarray(0.4), jnp.asarray(0.1),
                                          jnp.asarray(0.05))
    ref = _loop(v, [-0.3, 1.0], [0.3, 1.0], -0.8, 0.2,
                lambda u, y: (u - 0.4 * np.tanh(y / 0.05) - 0.1 * y, 0.0))
    np.testing.assert_allclose(np.asarray(hbjax.simulate(fx, v)), ref, atol=1e-10)


def test_friction_in_loop_predicts_as_the_plain_loop():
    """The one-step prediction (the diagnosis' criterion) puts the measured output in the
    law; it is computed without a scan, so it is checked on its own."""
    model = _system()
    rng = np.random.default_rng(3)
    v = np.repeat(rng.uniform(-3, 3, 30), 10)
    y_meas = np.asarray(hbjax.simulate(model, v)) + 0.1 * rng.standard_normal(len(v))
    fx = hbjax.EFFECTS["coulomb_friction"](model, jnp.asarray(0.4), jnp.asarray(0.1),
                                          jnp.asarray(0.05))
    ref = _loop(v, [-0.3, 1.0], [0.3, 1.0], -0.8, 0.2,
                lambda u, y: (u - 0.4 * np.tanh(y / 0.05) - 0.1 * y, 0.0), measured=y_meas)
    np.testing.assert_allclose(np.asarray(hbjax.predict(fx, v, y_meas)), ref, atol=1e-10)


def test_anchored_unmodeled_dynamics_is_a_lag_in_series():
    """``A (1 - p q^-1) y = g B (1 - z q^-1) u``, ``g = (1 - p) / (1 - z)``: the nominal
    poles and zeros kept, one pole and zero more, the static gain unchanged."""
    model = _system()
    v = np.repeat(np.random.default_rng(2).uniform(-3, 3, 30), 10)
    lag = hbjax.EFFECTS["unmodeled_dynamics"].anchored_form
    p, z = 0.7, -0.3
    fx = lag(model, jnp.asarray(p), jnp.asarray(z))
    assert fx.name == "unmodeled_dynamics"
    u, s = np.zeros(len(v)), 0.0
    for t in range(len(v)):
        s = min(max(s, -0.3 + v[t]), 0.3 + v[t])
        u[t] = s
    g = (1 - p) / (1 - z)
    a1, a2 = -0.8 - p, 0.8 * p
    y = np.zeros(len(v))
    for t in range(len(v)):
        y[t] = (-a1 * (y[t - 1] if t >= 1 else 0.0) - a2 * (y[t - 2] if t >= 2 else 0.0)
                + g * 0.2 * ((u[t - 1] if t >= 1 else 0.0) - z * (u[t - 2] if t >= 2 else 0.0)))
    np.testing.assert_allclose(np.asarray(hbjax.simulate(fx, v)), y, atol=1e-10)
    # the same static gain as the nominal model on a long plateau
    flat = np.full(400, 2.0)
    np.testing.assert_allclose(np.asarray(hbjax.simulate(fx, flat))[-1],
                               np.asarray(hbjax.simulate(model, flat))[-1], rtol=1e-9)


def _level_loop(a, b, u, alpha, outlet, depth, datum=None, measured=None):
    """The level law from the poles: each pole ``p`` moved to ``(1 + s x) / (1 - s x)``
    with ``x = (p - 1) / (p + 1)``, static gain ``1/s`` times the nominal one, around
    ``datum`` (the outlet unless given). With ``measured``: the one-step prediction, the
    measured output as the level and in the lags."""
    datum = outlet if datum is None else datum
    a, b = np.asarray(a, float), np.asarray(b, float)
    x = (np.roots(np.r_[1.0, a]) - 1) / (np.roots(np.r_[1.0, a]) + 1)
    A1 = 1 + a.sum()
    y = np.zeros(len(u))
    past = y if measured is None else np.asarray(measured, float)
    for t in range(len(u)):
        level = past[t - 1] if t >= 1 else 0.0
        s = (depth / max(abs(level - outlet), 1e-3 * depth)) ** alpha
        a_s = np.real(np.poly((1 + s * x) / (1 - s * x)))[1:]
        g = (1 + a_s.sum()) / (s * A1)
        acc = ((1 + a_s.sum()) * datum - g * A1 * datum) if t >= 1 else 0.0
        acc -= sum(a_s[i] * past[t - 1 - i] for i in range(len(a)) if t - 1 - i >= 0)
        acc += g * sum(b[j] * u[t - 1 - j] for j in range(len(b)) if t - 1 - j >= 0)
        y[t] = acc
    return y


@pytest.mark.parametrize("datum", [None, 0.0, 1.3])
@pytest.mark.parametrize("a, b", [([-0.8], [0.2]), ([-1.5, 0.6], [0.05, 0.04]),
                                  ([-1.2, 0.5, -0.08], [0.1, 0.0, 0.05])])
def test_level_dependent_matches_the_pole_law(a, b, datum):
    model = hbjax.Hammerstein(hbjax.Backlash(c1=[-0.3, 1.0], c2=[0.3, 1.0]),
                              hbjax.ARX(a=a, b=b))
    v = np.repeat(np.random.default_rng(1).uniform(1, 4, 30), 10)
    mean, std, depth = 2.0, 1.0, 2.5
    fx = hbjax.EFFECTS["level_dependent_dynamics"](
        model, jnp.asarray(0.5), jnp.asarray(np.log(depth / std)), jnp.asarray(mean),
        jnp.asarray(std), None if datum is None else jnp.asarray(datum))
    u = np.asarray(hbjax.play(model.backlash, v))
    ref = _level_loop(a, b, u, 0.5, mean - depth, depth, datum)
    np.testing.assert_allclose(np.asarray(hbjax.simulate(fx, v)), ref, atol=1e-9)
    # the fitted parameter vector gives back the same law
    again = type(fx).from_params(model, fx.params(), jnp.asarray([1.0, mean, std, 1.0]))
    np.testing.assert_allclose(np.asarray(hbjax.simulate(again, v)), ref, atol=1e-9)
    # the one-step prediction: the measured level sets the law
    y_meas = ref + 0.05 * np.random.default_rng(2).standard_normal(len(v))
    ref_pred = _level_loop(a, b, u, 0.5, mean - depth, depth, datum, measured=y_meas)
    np.testing.assert_allclose(np.asarray(hbjax.predict(fx, v, y_meas)), ref_pred, atol=1e-9)


def test_level_dependent_first_order_is_torricelli_in_equilibrium():
    """On a long plateau the level settles where the outflow, ``k sqrt(y - outlet)``,
    balances the inflow ``b u - A(1) outlet``: Torricelli's law."""
    model = _system()
    mean, std, depth = 2.0, 1.0, 2.5
    fx = hbjax.EFFECTS["level_dependent_dynamics"](
        model, jnp.asarray(0.5), jnp.asarray(np.log(depth / std)), jnp.asarray(mean),
        jnp.asarray(std))
    outlet = mean - depth
    for level_in in (1.0, 2.5, 4.0):
        y = float(np.asarray(hbjax.simulate(fx, np.full(600, level_in)))[-1])
        u = level_in - 0.3  # the backlash output on a rising plateau
        k = 0.2 * np.sqrt(depth)  # A(1) depth^alpha
        assert k * np.sqrt(y - outlet) == pytest.approx(0.2 * u - 0.2 * outlet, rel=1e-8)


def test_periodic_disturbance_at_an_input_harmonic_is_not_unrelated():
    t = np.arange(2000)
    v = np.sin(2 * np.pi * t / 100)
    model = _system()
    d = hbjax.EFFECTS["periodic_disturbance"](model, jnp.asarray(0.03), jnp.asarray(0.1),
                                             jnp.asarray(0.0))
    info = {"v": v, "y": v}
    text = d.describe(None, info)
    assert "unrelated" not in text["physics"].split("not a")[0]
    assert text["evidence"]["harmonic_of_input"]["order"] == 3
    d2 = hbjax.EFFECTS["periodic_disturbance"](model, jnp.asarray(0.0437), jnp.asarray(0.1),
                                              jnp.asarray(0.0))
    assert "unrelated to the input" in d2.describe(None, info)["physics"]


@pytest.mark.slow
@pytest.mark.parametrize("effect", ["coulomb_friction", "level_dependent_dynamics",
                                    "harmonic_distortion"])
def test_new_effect_named_over_seeds(effect):
    """A statistic over seeds: the right effect is the best finding on at least 2 of 3
    recordings. The seeds run in order until that is decided either way (two hits, or two
    misses): the verdict is the one all three would give."""
    hits, misses = [], []
    for seed in range(3):
        c = concealed_case(np.random.default_rng(500 + seed), effect, n=1500)
        d = hbjax.diagnose(c["nominal_model"], c["v"], c["y"], progress=False)
        if d.best is not None and d.best.effect == effect:
            assert d.best.fit_after > d.best.fit_before
            hits.append(seed)
        else:
            misses.append((seed, d.best and d.best.effect))
        if len(hits) == 2 or len(misses) == 2:
            break
    assert len(hits) >= 2, misses


def test_settling_drift_follows_its_exponential():
    """The drift of the equation in ``OffsetDrift``: linear at ``decay = 0``, and
    ``rate (1 - exp(-decay t)) / decay`` otherwise, against NumPy."""
    model = _system()
    v = np.repeat(np.random.default_rng(4).uniform(-3, 3, 40), 10)
    t = np.arange(v.size, dtype=float)
    base = np.asarray(hbjax.simulate(model, v))
    for decay, shape in ((0.0, t), (0.01, (1 - np.exp(-0.01 * t)) / 0.01),
                         (-0.002, (1 - np.exp(0.002 * t)) / -0.002)):
        fx = hbjax.EFFECTS["offset_drift"](model, jnp.asarray(0.3), jnp.asarray(0.02),
                                          jnp.asarray(decay))
        np.testing.assert_allclose(np.asarray(hbjax.simulate(fx, v)), base + 0.3 + 0.02 * shape,
                                   atol=1e-10)


@pytest.mark.slow
def test_settling_drift_is_named_as_a_settling_drift():
    """A statistic over the first three settling drifts (``1 - exp(-t / tau)``, tau 0.3-1.5
    record lengths) of the independent generator from seed 700 on: at least two are named
    ``offset_drift`` with a fitted drift that settles (``decay > 0``, time constant within
    0.1-5 record lengths). With the drift linear only, 3 of 5 such records of the study
    seeds 1366-1367 were named a parameter change."""
    hits, misses, seed = [], [], 700
    while len(hits) + len(misses) < 3:
        c = concealed_case(np.random.default_rng(seed), "offset_drift", n=2000)
        seed += 1
        if "exponential" not in c["truth"]["shape"]:
            continue
        d = hbjax.diagnose(c["nominal_model"], c["v"], c["y"], progress=False)
        best = d.best
        if best is not None and best.effect == "offset_drift" and float(best.model.decay) > 0:
            tau = 1.0 / float(best.model.decay)
            if 0.1 * 2000 < tau < 5 * 2000 and "settling" in best.physics:
                hits.append(seed - 1)
                continue
        misses.append((seed - 1, best and best.effect, best and float(getattr(best.model, "decay", 0))))
        if len(misses) == 2:
            break
    assert len(hits) >= 2, misses


def test_clipped_fraction_does_not_depend_on_the_output_unit():
    # The clip mask's tolerance is relative: an absolute floor of 1e-9 took every sample
    # of the same record in units 1e-12 for clipped.
    import jax

    rec = hbjax.concealed_recording("output_saturation", n=600, key=jax.random.PRNGKey(0))
    m, v, y = rec.model, np.asarray(rec.v), np.asarray(rec.y)
    fractions = []
    for scale in (1.0, 1e-12):
        scaled = hbjax.Hammerstein(m.backlash, hbjax.ARX(a=m.arx.a, b=m.arx.b * scale))
        d = hbjax.diagnose(scaled, v, y * scale, progress=False,
                           effects=["output_saturation"])
        assert d.best is not None and d.best.effect == "output_saturation", d.summary()
        fractions.append(d.best.parameters["clipped_fraction"])
    assert 0.0 < fractions[0] < 0.5 and abs(fractions[1] - fractions[0]) < 1e-12, fractions
