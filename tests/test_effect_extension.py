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
