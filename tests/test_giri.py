"""The paper's closed-form identification (sections 4-5)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hbjax
from hbjax._identify.giri import estimate_giri


def _experiments(model, design, N, noise_std, key):
    keys = jax.random.split(key, 3)
    vs = [jnp.asarray(design.constant_input(N)), jnp.asarray(design.binary_input(N)),
          jnp.asarray(design.staircase_input(N))]
    return [model.simulate_trajectory(v, noise_std * jax.random.normal(k, (N,)), 0.0)
            for v, k in zip(vs, keys)]


def test_noise_free_recovery_is_exact(system, design):
    ys = _experiments(system, design, 2000, 0.0, jax.random.PRNGKey(0))
    res = hbjax.identify_giri(design, *ys)
    truth = hbjax.flatten_params(hbjax.normalise(system, design.h_m))
    np.testing.assert_allclose(hbjax.flatten_params(res.model), truth, atol=1e-8)
    assert res.result == hbjax.RESULTS.successful
    assert float(res.gap) == pytest.approx(1.0, abs=1e-9)
    assert res.rows_ls == 2000 - design.n
    assert int(res.transient) > 0 and int(res.samples_offset) == 2000 - int(res.transient)
    assert np.all(np.asarray(res.plateaus) == 2000 // design.staircase_period + (np.arange(6) * 3 + 2 < 2000 % 18))


def test_noise_free_recovery_other_orders():
    model = hbjax.Hammerstein(hbjax.Backlash([-0.5, 1.0, 0.0, 0.01], [0.6, 1.1, 0.0, 0.0]),
                              hbjax.ARX([-0.7, 0.1, 0.05], [0.0, 1.0, -0.3]))
    design = hbjax.GiriDesign(3, 4, 3.0)
    ys = _experiments(model, design, 3000, 0.0, jax.random.PRNGKey(1))
    res = hbjax.identify_giri(design, *ys, v1=design.constant_input(3000),
                              v2=design.binary_input(3000), v3=design.staircase_input(3000))
    truth = hbjax.flatten_params(hbjax.normalise(model, design.h_m))
    np.testing.assert_allclose(hbjax.flatten_params(res.model), truth, atol=1e-7)


@pytest.mark.slow
def test_consistency_rmse_falls_like_inverse_sqrt_n(system, design):
    truth = np.asarray(hbjax.flatten_params(hbjax.normalise(system, design.h_m)))
    lengths = [1_000, 10_000, 100_000]
    rmse = []
    for N in lengths:
        def one(key):
            return hbjax.flatten_params(estimate_giri(design, *_experiments(system, design, N, 0.5, key)).model)

        est = np.asarray(jax.jit(jax.vmap(one))(jax.random.split(jax.random.PRNGKey(7), 100)))
        rmse.append(np.sqrt(np.mean((est - truth) ** 2, axis=0)))
    rmse = np.array(rmse)
    assert np.all(rmse[1:] < rmse[:-1])
    slopes = np.polyfit(np.log(lengths), np.log(rmse), 1)[0]
    assert np.all((slopes > -0.6) & (slopes < -0.4)), slopes


def test_bad_inputs(system, design):
    ys = _experiments(system, design, 200, 0.1, jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="`y2` has 5 samples"):
        hbjax.identify_giri(design, ys[0], ys[1][:5], ys[2])
    with pytest.raises(ValueError, match="`y3`.*one period 2m\\(n\\+1\\)"):
        hbjax.identify_giri(design, ys[0], ys[1], ys[2][:10])
    bad = np.array(ys[0])
    bad[17] = np.nan
    with pytest.raises(ValueError, match="`y1` contains NaN.*index 17"):
        hbjax.identify_giri(design, bad, ys[1], ys[2])
    with pytest.raises(ValueError, match="`y1` must be a 1-D array"):
        hbjax.identify_giri(design, np.ones((10, 2)), ys[1], ys[2])
    v2 = design.binary_input(200)
    v2[3] = 0.5
    with pytest.raises(ValueError, match="`v2` must take values in"):
        hbjax.identify_giri(design, *ys, v2=v2)
    with pytest.raises(TypeError, match="`design`"):
        hbjax.identify_giri("n=2", *ys)
    with pytest.raises(ValueError, match="`h_m` must be a finite number > 0"):
        hbjax.GiriDesign(2, 3, 0.0)
    with pytest.raises(ValueError, match="`n` must be an integer >= 1"):
        hbjax.GiriDesign(0, 3, 4.0)
    with pytest.raises(TypeError, match="`m` must be an integer"):
        hbjax.GiriDesign(2, 2.5, 4.0)


def test_zero_static_gain_is_refused(design):
    # B(1) = 0 (assumption A5): the levels of v3 cannot be read through the static gain.
    model = hbjax.Hammerstein(hbjax.default_system().backlash, hbjax.ARX([-1.2, 0.5], [1.0, -1.0]))
    ys = _experiments(model, design, 3000, 0.1, jax.random.PRNGKey(2))
    with pytest.raises(ValueError, match="B\\*\\(1\\) is not significantly different from 0"):
        hbjax.identify_giri(design, *ys)
    res = hbjax.identify_giri(design, *ys, throw=False)
    assert res.result == hbjax.RESULTS.zero_static_gain


def test_swing_that_does_not_cross_the_gap_is_reported(system):
    # h_m = 0.5 is below the branches' zeros (A4 fails): +-h_m stays inside the band.
    design = hbjax.GiriDesign(2, 3, 0.5)
    ys = _experiments(system, design, 3000, 0.1, jax.random.PRNGKey(3))
    res = hbjax.identify_giri(design, *ys, throw=False)
    assert res.result != hbjax.RESULTS.successful


def test_normalise_refuses_mu_zero():
    model = hbjax.Hammerstein(hbjax.Backlash([1.0, 0.0], [1.0, 0.0]), hbjax.ARX([-0.5], [1.0]))
    with pytest.raises(ValueError, match="mu = P2\\(-h_m\\) - P1\\(h_m\\) is 0"):
        hbjax.normalise(model, 2.0)
