"""Arguments at their edges, each refused or handled as documented (found by probing the
public API with inputs the package was not developed on)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hbjax

jax.config.update("jax_enable_x64", True)


def test_a_progress_dict_overrides_the_bars_own_options():
    study = hbjax.monte_carlo(hbjax.default_system(), hbjax.default_design(), noise_std=0.3,
                              lengths=[300], realisations=2, key=jax.random.key(0),
                              progress={"desc": "my study", "unit": "draw", "disable": True})
    assert study.n_valid.shape == (1,)


def test_a_repeated_device_is_refused_naming_devices():
    with pytest.raises(ValueError, match="`devices` must list each device once"):
        hbjax.monte_carlo(hbjax.default_system(), hbjax.default_design(), noise_std=0.3,
                          lengths=[300], realisations=2, key=jax.random.key(0),
                          progress=False, devices=jax.devices() * 2)


def test_a_custom_estimators_own_code_is_shown_as_its_number():
    """Codes are read in hbjax.RESULTS's table (docs/monte_carlo.md); one beyond it is the
    estimator's own and is shown as its number, not as some message of the table."""
    def rejecting(design, y1, y2, y3):
        res = hbjax.internal.estimate_giri(design, y1, y2, y3)

        class Out:
            model, result = res.model, jnp.asarray(9999, jnp.int32)
        return Out()

    study = hbjax.monte_carlo(hbjax.default_system(), hbjax.default_design(), noise_std=0.3,
                              lengths=[300], realisations=2, key=jax.random.key(0),
                              estimator=rejecting, progress=False)
    assert list(study.failure_counts()) == ["code 9999"]


@pytest.mark.parametrize("dtype, eps", [(jnp.float32, 1e-20), (jnp.float64, 1e-300)])
def test_a_vanishing_smoothing_gives_the_exact_operators_gradients(dtype, eps):
    model = jax.tree_util.tree_map(lambda x: x.astype(dtype), hbjax.default_system())
    v = jnp.asarray(np.random.default_rng(0).uniform(-8, 8, 200), dtype)
    loss = lambda smoothing: lambda v: jnp.sum(hbjax.simulate(model, v, smoothing=smoothing) ** 2)
    tiny, exact = jax.grad(loss(eps))(v), jax.grad(loss(0.0))(v)
    assert bool(jnp.all(jnp.isfinite(tiny)))
    np.testing.assert_allclose(np.asarray(tiny), np.asarray(exact), rtol=1e-4, atol=1e-4)


def test_the_relaxed_step_has_finite_gradients_at_tiny_magnitudes():
    from hbjax._core.relaxed import relaxed_step

    for dtype in (jnp.float32, jnp.float64):
        args = [jnp.asarray(x, dtype) for x in (-1e-20, 3e-20, 1e-20, 1e-7)]
        grads = jax.grad(lambda lo, hi, u, e: relaxed_step(lo, hi, u, e), argnums=(0, 1, 2, 3))(
            *args)
        assert all(bool(jnp.isfinite(g)) for g in grads), (dtype, grads)


def test_a_finite_value_beyond_the_computing_dtype_is_named_not_called_inf():
    """(With 64-bit floats off, float64 data is computed in float32; here the dtype is
    asked for directly, since this process runs with them on.)"""
    from hbjax._misc import as_float_array

    with pytest.raises(ValueError, match=r"`v` reaches a magnitude of 5e\+38, beyond the "
                                         r"largest float32"):
        as_float_array(np.array([0.0, 1.0, 5e38, 2.0]), "v", dtype=jnp.float32)
    with pytest.raises(ValueError, match="`v` contains NaN or inf"):
        hbjax.simulate(hbjax.default_system(), np.array([0.0, np.inf]))


def test_a_record_whose_output_never_moves_has_no_fit_percent():
    # A dead sensor: its free-run fit percent is undefined (as fit_percent says), not a
    # number of -1e152 % from dividing by no spread.
    rng = np.random.default_rng(0)
    model = hbjax.default_system()
    v = np.repeat(rng.uniform(-8, 8, 60), 10)
    good = (v, np.asarray(hbjax.simulate(model, v, 0.1 * rng.normal(size=600))))
    for level in (0.0, 0.1):  # (the mean of a constant 0.1 leaves rounding in its spread)
        res = hbjax.fit([good, (v, np.full(600, level))], na=2, nb=2, m=3,
                        key=jax.random.key(0), starts=2, throw=False, progress=False)
        fits = np.asarray(res.sim_fit)
        assert np.isfinite(fits[0]) and np.isnan(fits[1]), fits
        assert np.isfinite(float(res.sim_fit_pooled))
        assert "undefined (output constant)" in str(res.summary())


def test_a_batched_model_is_refused_naming_it():
    m = hbjax.default_system()
    batched = jax.vmap(lambda s: hbjax.Hammerstein(
        hbjax.Backlash(m.backlash.c1 * s, m.backlash.c2), m.arx))(jnp.ones(2))
    v = jnp.linspace(-5.0, 5.0, 10)
    for call in (lambda: hbjax.simulate(batched, v), lambda: hbjax.predict(batched, v, v)):
        with pytest.raises(ValueError, match="`model` is batched"):
            call()
    with pytest.raises(ValueError, match="`backlash` is batched"):
        hbjax.play(batched.backlash, v)
    # one at a time under vmap, as the message says
    out = jax.vmap(lambda one: hbjax.simulate(one, v))(batched)
    assert out.shape == (2, 10)
    # a relaxed backlash holds a scalar smoothing: one backlash, not a batch
    from hbjax._core.relaxed import relax

    assert hbjax.play(relax(m.backlash, 0.1), v).shape == (10,)


def test_a_custom_estimator_of_other_orders_is_refused_naming_them():
    import equinox as eqx

    class Outcome(eqx.Module):
        model: hbjax.Hammerstein
        result: jax.Array

    def estimator(design, y1, y2, y3):
        return Outcome(hbjax.Hammerstein(hbjax.Backlash(jnp.zeros(2), jnp.ones(2)),
                                         hbjax.ARX(jnp.zeros(1), jnp.ones(1))), jnp.int32(0))

    with pytest.raises(ValueError, match=r"orders \(na, nb, m\) = \(2, 2, 3\), got \(1, 1, 2\)"):
        hbjax.monte_carlo(hbjax.default_system(), hbjax.default_design(), noise_std=0.1,
                          lengths=[200], realisations=2, key=jax.random.key(0),
                          estimator=estimator, progress=False)


def test_a_concealed_recording_shows_its_arrays_by_shape_and_range():
    rec = hbjax.concealed_recording("output_saturation", n=1000, key=jax.random.key(0))
    text = repr(rec)
    assert "f64[1000]" in text and "effect='output_saturation'" in text and len(text) < 2000


def test_fit_refuses_records_whose_output_never_moves_naming_them():
    # (every start's least squares gave B = 0, reported as a gauge the user never chose)
    v = 0.5 + 0.3 * np.sin(2 * np.pi * np.arange(300) / 50)
    with pytest.raises(ValueError, match="`recordings`: the output y is constant in every"):
        hbjax.fit((v, np.zeros(300)), na=2, nb=2, m=3, key=jax.random.key(0),
                  progress=False)


def test_an_output_constant_up_to_rounding_is_refused_alike_everywhere():
    # One rule (`no_spread`) for fit, diagnose and compare: a level held at 5 whose samples
    # differ only in the last bit was refused by compare but fitted and diagnosed before.
    v = 5.0 * np.sin(0.05 * np.arange(600))
    y = np.full(600, 5.0)
    y[::7] = np.nextafter(5.0, 6.0)
    with pytest.raises(ValueError, match="`recordings`: the output y is constant in every"):
        hbjax.fit((v, y), na=1, nb=1, m=2, key=jax.random.key(0), progress=False)
    with pytest.raises(ValueError, match="`y` is constant"):
        hbjax.diagnose(hbjax.default_system(), v, y, progress=False)
    with pytest.raises(ValueError, match="`y` is constant"):
        hbjax.compare(hbjax.default_system(), v, y)
