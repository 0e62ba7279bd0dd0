"""The level law of two stores in series (an unmeasured upper level): named on records of a
cascade of tanks written from the physics (tests/generators/two_tanks.py, not the package's
equations), by the output-error criterion and by the plain path with the defaults, and not on
records of the paper's model under either criterion."""

import equinox as eqx
import jax
import numpy as np
import pytest
from generators.concealed_effects import concealed_case
from generators.two_tanks import pump_voltage, random_tanks, simulate_tanks

import hbjax

jax.config.update("jax_enable_x64", True)

ROW = "level_dependent_dynamics (two levels in series, overflow)"


def tanks_record(seed, n=2000):
    rng = np.random.default_rng(seed)
    plant = random_tanks(rng, overflow=seed % 2 == 0, clip=seed % 3 != 0)
    p = pump_voltage(rng, n, "plateaus" if seed % 2 else "multisine")
    y, levels = simulate_tanks(plant, p, rng)
    return p, y, levels, plant


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 4])
def test_two_tanks_named_with_a_held_out_gain(seed):
    v, y, _, plant = tanks_record(seed)
    n_fit = int(0.7 * len(v))
    # the nominal model from the fitting part only, as a user would identify it
    start = hbjax.identify_nominal(v[:n_fit], y[:n_fit], na=2, nb=2, m=3)
    nominal = hbjax.identify_nominal(v[:n_fit], y[:n_fit], start=start, criterion="simulation",
                                     transient=100)
    d = hbjax.diagnose(nominal, v, y, criterion="simulation", progress=False)
    row = d.candidates[ROW]
    assert row["decision"] == "reported", row
    f = d.best
    assert f is not None and f.effect == "level_dependent_dynamics", d.summary()
    assert f.metric == "simulation" and f.fit_after > f.fit_before + 5
    assert f.evidence["dm_z"] > 2 and f.evidence["dm_z_over_constant"] > 2
    if plant["clip"]:  # the sensor's range read from the record's plateaus
        assert f.parameters["sensor_range"][1] == pytest.approx(float(np.max(y)))
    # its one-step predictor on its own noise-free free run gives that free run back
    open_range = eqx.tree_at(lambda m: (m.lower, m.upper), f.model, (None, None),
                             is_leaf=lambda x: x is None)
    free = np.asarray(hbjax.simulate(open_range, v))
    np.testing.assert_allclose(np.asarray(hbjax.predict(open_range, v, free)), free,
                               rtol=1e-9, atol=1e-9 * np.ptp(free))
    # the model runs on a record of its own, its two levels estimated there
    rng = np.random.default_rng(100 + seed)
    p2 = pump_voltage(rng, 1000, "multisine")
    y2, _ = simulate_tanks(plant, p2, rng)
    c = hbjax.compare([nominal, f.model], p2, y2, initial_state="estimate")
    assert c.fit[1] > c.fit[0], c.summary()


@pytest.mark.slow
def test_two_tanks_named_by_the_plain_path():
    """The nominal model by `fit` on the whole record, `diagnose` on that record with its
    defaults (one-step prediction): the nominal model saw the held-out part, and the other
    candidates' BIC is on another criterion than the level law's."""
    rng = np.random.default_rng(22)
    plant = random_tanks(rng, overflow=True, clip=True)
    p = pump_voltage(rng, 1800, "plateaus")
    y, _ = simulate_tanks(plant, p, rng)
    nominal = hbjax.fit((p, y), na=2, nb=2, m=3, key=jax.random.key(22), criterion="simulation",
                        progress=False).model
    d = hbjax.diagnose(nominal, p, y, progress=False)
    f = d.best
    assert f is not None and f.effect == "level_dependent_dynamics", d.summary()
    assert f.evidence["bic_criterion"] == "simulation"
    assert f.evidence["dm_z_vs_refit"] > 2 and f.fit_after > f.fit_before
    # every mechanism after it simulates the held-out part worse
    for g in d.findings[1:]:
        if g.mechanism:
            assert g.fit_after < f.fit_after, d.summary()


@pytest.mark.slow
@pytest.mark.parametrize("criterion", ["simulation", "prediction"])
def test_not_named_on_records_of_the_paper_model(criterion):
    rng = np.random.default_rng(7)
    reported = []
    for kind in ("plateaus", "multisine", "noise"):
        case = concealed_case(rng, None, input_kind=kind, n=1500)
        d = hbjax.diagnose(case["nominal_model"], case["v"], case["y"], criterion=criterion,
                           progress=False)
        row = d.candidates.get(ROW)
        reported.append(row is not None and row["decision"] == "reported")
        assert all(f.effect != "level_dependent_dynamics" for f in d.findings), d.summary()
    assert not any(reported)


def test_model_file_checked_on_load(tmp_path):
    import json

    import jax.numpy as jnp

    from hbjax._diagnose.level_cascade import LevelCascade

    base = concealed_case(np.random.default_rng(0), None, n=1000)["nominal_model"]
    model = LevelCascade(base, jnp.asarray([0.1, 0.0, 0.05, -2.0, 0.05, 0.05, -2.0, 3.0, 0.5]),
                         jnp.asarray([0.5, 0.0]), 1.0, 2.0, 0.5, None, 3.0, "internal")
    path = hbjax.save_model(tmp_path / "cascade.json", model)
    v = np.sin(np.arange(300) / 20.0)
    np.testing.assert_array_equal(np.asarray(hbjax.simulate(hbjax.load_model(path), v)),
                                  np.asarray(hbjax.simulate(model, v)))
    for field, value, message in (("feed", "os.system", "`LevelCascade.feed` must be one of"),
                                  ("y_scale", -1.0, "`LevelCascade.y_scale` must be > 0")):
        doc = json.loads(path.read_text())
        doc["model"]["fields"][field] = value
        bad = tmp_path / f"bad_{field}.json"
        bad.write_text(json.dumps(doc))
        with pytest.raises(ValueError, match=message):
            hbjax.load_model(bad)


def test_time_constants_are_the_inverse_slope_of_the_outflow():
    """Each store's local time constant at a level is the inverse slope of its outflow
    there (a small step in the level decays by that factor per sample), computed here by a
    finite difference of Torricelli's law written out, at the 10th and 90th percentiles of
    the recorded level (measured store) and of the upstream level simulated by a NumPy
    loop of the upstream equation (with the overflow cap)."""
    import jax.numpy as jnp

    from hbjax._diagnose.level_cascade import LevelCascade, time_constants

    base = concealed_case(np.random.default_rng(0), None, n=1000)["nominal_model"]
    rng = np.random.default_rng(5)
    for _ in range(5):
        g, c, k1, o1 = rng.uniform(0.05, 0.2), 0.0, rng.uniform(0.02, 0.2), rng.uniform(-3, -1)
        k3, o2, h = rng.uniform(0.02, 0.5), rng.uniform(-3.0, -1.5), rng.uniform(0.0, 1.0)
        center, scale = rng.uniform(-2, 2), rng.uniform(0.2, 3.0)
        params = jnp.asarray([g, c, k1, o1, 0.05, k3, o2, h, 0.5])
        model = LevelCascade(base, params, jnp.asarray([0.5, 0.0]), 1.0, center, scale)
        y = center + scale * rng.uniform(-1.0, 1.0, 4000)
        v = 1.5 + 0.5 * np.sin(np.arange(4000) / rng.uniform(20, 80))  # keeps it filled
        x1, upstream = 0.5, []
        for w in v:
            upstream.append(x1)
            x1 = min(x1 + g * w + c - k1 * np.sqrt(max(x1 - o1, 0.0) + 1e-12), h)
        taus = time_constants(model, v, y)

        def inverse_slope(x, k, outlet, dx=1e-6):
            return 2 * dx / (k * (np.sqrt(x + dx - outlet) - np.sqrt(x - dx - outlet)))

        for levels, k, outlet, got in (((y - center) / scale, k3, o2, taus["measured"]),
                                       (np.asarray(upstream), k1, o1, taus["upstream"])):
            for q, t in zip(np.quantile(levels, [0.1, 0.9]), got):
                assert t == pytest.approx(inverse_slope(q, k, outlet), rel=1e-5)
            # deeper levels drain slower (Torricelli): the time constant grows with the level
            assert got[1] >= got[0]
