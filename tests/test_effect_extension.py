"""Adding an effect to the diagnosis is writing one class: a toy effect defined here (an
additive output step at a fitted time) is fitted and reported by hbjax.diagnose on data
that contain it, through the generic path of hbjax.AbstractEffect, with no other module
changing; the built-in effects are classes of the same base, registered by name."""

from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jaxtyping import Array, Float

import hbjax

WIDTH = 2.0  # samples over which the step rises


class OutputStep(hbjax.AbstractEffect):
    """An additive step in the output: ``y = y_lin + height * sigmoid((t - time) / 2)``."""

    base: hbjax.Hammerstein
    height: Float[Array, ""]
    time: Float[Array, ""]

    name: ClassVar[str] = "output_step"
    n_params: ClassVar[int] = 2

    def output_term(self, v, u, y_lin):
        t = jnp.arange(y_lin.shape[0], dtype=y_lin.dtype)
        return self.height * jax.nn.sigmoid((t - self.time) / WIDTH)

    @classmethod
    def start(cls, ctx):
        # the largest mean shift of the nominal simulation residual (a CUSUM)
        r = (ctx.y_fit - ctx.y_sim_nom)[ctx.burn:]
        k = int(np.argmax(np.abs(np.cumsum(r - r.mean())[:-1]))) + 1
        return np.array([r[k:].mean() - r[:k].mean(), ctx.burn + k])

    @classmethod
    def scales(cls, ctx):
        return np.array([float(np.std(ctx.y_fit)), 10.0])

    def describe(self, ctx, info):
        t, h = float(self.time), float(self.height)
        return {
            "physics": f"The output steps by {h:.3g} at sample {t:.0f}: a sensor re-zeroed "
                       "or a load added.",
            "where": {"windows": [[int(t), len(info["y"])]], "regime": "after the step"},
            "parameters": {"height": h, "time": t},
        }


N, T0 = 1500, 600


@pytest.fixture(scope="module")
def recordings():
    rec = hbjax.concealed_recording(None, system=0, n=N, noise=0.02, key=jax.random.PRNGKey(11))
    height = 0.4 * float(np.std(rec.y))
    truth = OutputStep(rec.model, jnp.asarray(height), jnp.asarray(float(T0)))
    step = np.asarray(hbjax.simulate(truth, rec.v)) - np.asarray(hbjax.simulate(rec.model, rec.v))
    return rec, truth, rec.y + step


def test_generic_effect_simulates_and_predicts(recordings):
    rec, truth, y = recordings
    t = np.arange(N)
    term = float(truth.height) / (1 + np.exp(-(t - T0) / WIDTH))
    xi = 0.01 * np.random.default_rng(0).standard_normal(N)
    np.testing.assert_allclose(hbjax.simulate(truth, rec.v, xi),
                               np.asarray(hbjax.simulate(rec.model, rec.v, xi)) + term, atol=1e-10)
    # one-step predictor y - A (y - y_sim): the ARX predictor shifted by A applied to the term
    a = np.asarray(rec.model.arx.a)
    a_term = term + sum(a[i] * np.concatenate([np.zeros(i + 1), term[:-(i + 1)]])
                        for i in range(len(a)))
    np.testing.assert_allclose(hbjax.predict(truth, rec.v, y),
                               np.asarray(hbjax.predict(rec.model, rec.v, y)) + a_term, atol=1e-9)
    table = truth.parameter_table()
    assert [r[0] for r in table.rows] == ["height", "time"]


def test_toy_effect_is_fitted_and_reported(recordings):
    rec, truth, y = recordings
    d = hbjax.diagnose(rec.model, rec.v, y,
                       effects=["offset_drift", "parameter_change", OutputStep], progress=False)
    f = d.best
    assert f is not None and f.effect == "output_step", d.summary()
    assert isinstance(f.model, OutputStep)
    assert abs(f.parameters["time"] - T0) <= 3
    assert f.parameters["height"] == pytest.approx(float(truth.height), rel=0.1)
    assert f"at sample {f.parameters['time']:.0f}" in f.physics  # built from the fitted values
    assert f.fit_after > f.fit_before
    assert {"output_step", "offset_drift", "parameter_change", "parameter_mismatch"} <= set(d.candidates)
    assert d.candidates["output_step"]["k"] == d.candidates["parameter_mismatch"]["k"] + 2
    # the anchored variant: base held at the nominal values, only the effect's parameters
    held = d.candidates["output_step (nominal base)"]
    assert held["k"] == 2 and 0.0 <= held["base_p"] <= 1.0
    assert f.evidence["base"] in ("nominal (held)", "refitted")
    if f.evidence["base"] == "nominal (held)":
        np.testing.assert_array_equal(np.asarray(f.model.base.arx.a), np.asarray(rec.model.arx.a))
        assert held["bic"] <= d.candidates["output_step"]["bic"]
    assert "output_step" not in hbjax.EFFECTS  # the registry did not change
    assert np.all(np.isfinite(np.asarray(hbjax.simulate(f.model, rec.v))))


def test_toy_effect_not_reported_on_clean_data(recordings):
    rec, _, _ = recordings
    d = hbjax.diagnose(rec.model, rec.v, rec.y,
                       effects=["offset_drift", "parameter_change", OutputStep], progress=False)
    assert "output_step" in d.candidates
    assert d.best is None, d.summary()


def test_registry_is_built_from_effect_classes():
    for name, cls in hbjax.EFFECTS.items():
        assert issubclass(cls, hbjax.AbstractEffect) and cls.name == name
        assert not getattr(cls, "__abstractmethods__", None)
    assert len({cls.__name__ for cls in hbjax.EFFECTS.values()}) == len(hbjax.EFFECTS)


def test_effects_argument_is_checked(system):
    v = np.sin(np.arange(1000) / 10.0) * 8
    y = np.asarray(hbjax.simulate(system, v))
    with pytest.raises(ValueError, match="unknown effect"):
        hbjax.diagnose(system, v, y, effects=[int])
    with pytest.raises(TypeError, match="abstract"):
        hbjax.diagnose(system, v, y, effects=[hbjax.AbstractEffect])


# --- the effects' parameter constraints (AbstractEffect.constraints) ---------------------

FX = hbjax.EFFECTS


@pytest.mark.parametrize("build, error, match", [
    # numeric, not a string, a boolean or None (unless the field is optional)
    (lambda m: FX["output_saturation"](m, None, "abc"), TypeError, r"OutputSaturation\.upper"),
    (lambda m: FX["input_saturation"](m, True, None), TypeError, r"InputSaturation\.lower"),
    (lambda m: FX["offset_drift"](m, None, 0.0), TypeError, r"OffsetDrift\.offset.*None"),
    # finite
    (lambda m: FX["output_saturation"](m, None, jnp.nan), ValueError, r"upper` must be finite"),
    (lambda m: FX["output_saturation"](m, -jnp.inf, 1.0), ValueError, r"lower` must be finite"),
    (lambda m: FX["harmonic_distortion"](m, 0.0, jnp.inf, 0.0, 1.0), ValueError,
     r"HarmonicDistortion\.h2` must be finite"),
    # the documented shape: a scalar, a fixed length or the base's orders
    (lambda m: FX["output_saturation"](m, None, jnp.ones(3)), ValueError,
     r"upper` must be a scalar, got shape \(3,\)"),
    (lambda m: FX["colored_noise"](m, jnp.zeros(3)), ValueError, r"ColoredNoise\.d.*\(2,\)"),
    (lambda m: FX["parameter_change"](m, 5, jnp.zeros(3), jnp.zeros(2), jnp.zeros(3),
                                      jnp.zeros(3)), ValueError, r"ParameterChange\.da.*\(2,\)"),
    # ordered pair: a clip's lower level below its upper one
    (lambda m: FX["output_saturation"](m, jnp.asarray(5.0), jnp.asarray(3.0)), ValueError,
     r"OutputSaturation\.lower` \(5\.0\) must be below"),
    (lambda m: FX["input_saturation"](m, 2.0, 2.0), ValueError, "must be below"),
    # positive widths and scales
    (lambda m: FX["coulomb_friction"](m, 0.1, 0.0, 0.0), ValueError,
     r"CoulombFrictionInLoop\.width` must be > 0"),
    (lambda m: FX["level_dependent_dynamics"](m, 0.5, 0.0, 1.0, -1.0), ValueError,
     r"y_std` must be > 0"),
    # a delay or change time: a non-negative integer within the kernel's range
    (lambda m: FX["extra_delay"](m, 2.5), TypeError, r"ExtraDelay\.delay` must be an integer"),
    (lambda m: FX["extra_delay"](m, -1), ValueError, r"ExtraDelay\.delay"),
    (lambda m: FX["extra_delay"](m, 13), ValueError, r"ExtraDelay\.delay` must be in \[0, 12\]"),
    (lambda m: FX["parameter_change"](m, -3, *(jnp.zeros(k) for k in (2, 2, 3, 3))),
     ValueError, r"ParameterChange\.time"),
])
def test_effect_constructors_check_their_parameters(system, build, error, match):
    with pytest.raises(error, match=match):
        build(system)


def test_valid_effects_and_traced_values_pass(system):
    ok = FX["output_saturation"](system, None, 3)  # an open side; an integer level
    assert ok.upper == 3
    FX["extra_delay"](system, 0)
    # NumPy integers (a delay from np.argmin, a change time from a search) are stored as
    # Python ints: no static JAX/NumPy scalar in the tree, and equal models hash alike
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        delayed = FX["extra_delay"](system, np.int64(3))
        changed = FX["parameter_change"](system, np.int64(5), jnp.zeros(2), jnp.zeros(2),
                                         jnp.zeros(3), jnp.zeros(3))
    assert type(delayed.delay) is int and type(changed.time) is int
    assert delayed == FX["extra_delay"](system, 3)
    FX["input_saturation"](system, jnp.asarray(-2.0), jnp.asarray(3.0))
    # traced values: shape and type are checked, values (unknown while tracing) are not
    v = jnp.linspace(-3, 3, 40)
    clip = jax.jit(lambda x: FX["output_saturation"](system, None, x).upper)
    assert bool(jnp.isnan(clip(jnp.nan)))
    levels = jax.vmap(lambda x: FX["output_saturation"](system, -x, x).upper)(jnp.ones(2))
    np.testing.assert_array_equal(levels, [1.0, 1.0])
    grad = jax.grad(lambda x: jnp.sum(hbjax.simulate(FX["input_saturation"](system, None, x), v)))
    assert np.isfinite(grad(2.0))
    with pytest.raises(ValueError, match="must be a scalar"):
        jax.jit(lambda x: FX["output_saturation"](system, None, x))(jnp.ones(2))


def test_a_new_effect_gets_checks_by_declaring_them(system):

    class TimedStep(OutputStep):
        constraints: ClassVar[dict] = {"height": hbjax.EffectConstraint(),
                                       "time": hbjax.EffectConstraint(minimum=0.0)}

    TimedStep(system, jnp.asarray(1.0), jnp.asarray(5.0))
    with pytest.raises(ValueError, match=r"TimedStep\.time` must be in \[0\.0, inf\]"):
        TimedStep(system, jnp.asarray(1.0), jnp.asarray(-5.0))
    OutputStep(system, jnp.asarray(1.0), jnp.asarray(-5.0))  # declares nothing: unchecked
