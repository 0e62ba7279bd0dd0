"""`fit`'s default criterion "auto" (hbjax/_identify/fit_criterion.py), on random paper-class
systems of the independent generator: the prediction result stands under equation noise,
and noise at the sensor, which biases it, is answered by the output-error refinement."""

import jax
import numpy as np
import pytest

import hbjax
from generators.paper_class import INPUT_KINDS, random_input, random_paper_system, simulate_numpy
from generators.paper_runs import noise_gain

pytestmark = pytest.mark.slow


def _validation_fit(model, v, y):
    return float(np.atleast_1d(hbjax.compare(model, v, y).fit)[0])


def test_auto_keeps_the_prediction_criterion_under_equation_noise_and_leaves_it_under_output_noise():
    # (inputs that move through their range: a few PRBS levels determine the branches only
    # at the levels, which fit refuses whatever the noise)
    kinds = [kind for kind in INPUT_KINDS if kind != "prbs_levels"]
    rng = np.random.default_rng(2024)
    gains, switched = [], 0
    for k in range(4):
        s = random_paper_system(rng, n=int(rng.integers(1, 4)), m=3)
        kind = kinds[k % len(kinds)]
        v = random_input(rng, kind, 2000, 1.5 * s["h_m"])
        y_clean = simulate_numpy(s, v)[0]
        v_val = random_input(rng, kind, 1500, 1.5 * s["h_m"])
        y_val = simulate_numpy(s, v_val)[0]
        sd = 0.03 * np.ptp(y_clean)
        fit = dict(na=s["na"], nb=s["nb"], m=3, key=jax.random.key(k), progress=False)

        # Equation noise: the paper's model (eq. (10)) holds, the one-step errors are white
        # and the prediction criterion (its maximum likelihood) is kept.
        y_eq = simulate_numpy(s, v, sd / noise_gain(s["a"]) * rng.standard_normal(v.size))[0]
        res = hbjax.fit((v, y_eq), **fit)
        assert res.criterion == "prediction", res.criterion_choice
        assert res.criterion_choice.startswith("auto: prediction (one-step errors white")

        # Noise at the output: the prediction optimum is biased (errors in variables).
        y_out = y_clean + sd * rng.standard_normal(v.size)
        auto = hbjax.fit((v, y_out), **fit)
        pred = hbjax.fit((v, y_out), criterion="prediction", **fit)
        assert auto.result == hbjax.RESULTS.successful
        if auto.criterion == "simulation":
            switched += 1
            assert "coloured" in auto.criterion_choice
            assert "criterion chosen" in str(auto.summary())
            # asked for, the prediction criterion's result is kept and says what is wrong
            assert pred.criterion == "prediction"
            assert pred.criterion_choice.startswith(
                "prediction, as asked; its one-step errors are coloured"), pred.criterion_choice
        gains.append(_validation_fit(auto.model, v_val, y_val)
                     - _validation_fit(pred.model, v_val, y_val))
    gains = np.array(gains)
    assert switched >= 3, gains
    # never worse on the held-out record, better on average
    assert np.all(gains > -0.5) and np.mean(gains) > 1.0, gains


def test_auto_is_refused_where_only_the_two_criteria_are_meant():
    v = np.sin(0.05 * np.arange(400))
    with pytest.raises(ValueError, match=r"`criterion` must be one of \('prediction', 'simulation'\)"):
        hbjax.refine(hbjax.default_system(), [(v, v)], criterion="auto")
    with pytest.raises(ValueError, match=r"`criterion` must be one of \('auto', 'prediction', 'simulation'\)"):
        hbjax.fit((v, v), na=1, nb=1, m=2, key=jax.random.key(0), criterion="equation")
