"""Monte Carlo studies (issue 4): semantics of one realisation, statistics, chunking and
device invariance, failure handling, bad input, and the paper's consistency claims."""

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hbjax
from hbjax._identify.giri import SINGULAR_LS, estimate_giri


KEY = jax.random.key(0)


def _study(system, design, **kw):
    opts = dict(noise_std=0.1, lengths=[200], realisations=6, key=KEY, progress=False,
                keep_estimates=True)
    opts.update(kw)
    return hbjax.monte_carlo(system, design, **opts)


def _noise_records(key, length, r, noise_std):
    """The documented draw: key fold_in(fold_in(key, N), r), split in three, float32
    normals used in float64."""
    k = jax.random.fold_in(jax.random.fold_in(key, length), r)
    draw = lambda kk: jax.random.normal(kk, (length,), jnp.float32).astype(jnp.float64)
    return noise_std * jax.vmap(draw)(jax.random.split(k, 3))


@pytest.fixture(scope="module")
def small_study():
    return _study(hbjax.default_system(), hbjax.default_design(), lengths=[200, 400])


def test_realisation_matches_simulate_and_identify_giri(system, design, small_study):
    # Every realisation is the public pipeline simulate -> identify_giri on the same noise.
    inputs = lambda n: (design.constant_input(n), design.binary_input(n), design.staircase_input(n))
    for i, n in enumerate(small_study.lengths):
        for r in (0, 5):
            xi = _noise_records(KEY, int(n), r, 0.1)
            ys = [hbjax.simulate(system, v, e) for v, e in zip(inputs(int(n)), xi)]
            res = hbjax.identify_giri(design, *ys)
            np.testing.assert_allclose(small_study.estimates[i, r],
                                       hbjax.flatten_params(res.model), rtol=1e-9, atol=1e-12)


def test_statistics_from_estimates(system, design, small_study):
    s = small_study
    true = np.asarray(hbjax.flatten_params(hbjax.normalise(system, design.h_m)))
    np.testing.assert_array_equal(s.true, true)
    assert s.names == tuple(hbjax.param_names(system))
    assert s.mean.shape == s.bias.shape == s.std.shape == s.rmse.shape == (2, true.size)
    assert s.estimates.shape == (2, 6, true.size)
    np.testing.assert_array_equal(s.n_valid, [6, 6])
    np.testing.assert_allclose(s.mean, s.estimates.mean(axis=1), rtol=1e-13)
    np.testing.assert_allclose(s.bias, s.estimates.mean(axis=1) - true, rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(s.std, s.estimates.std(axis=1, ddof=1), rtol=1e-12)
    np.testing.assert_allclose(
        s.rmse, np.sqrt(((s.estimates - true) ** 2).mean(axis=1)), rtol=1e-12)


def test_slope_fit_recovers_known_rate():
    from hbjax._montecarlo.study import _slope_fit

    lengths = np.array([100, 1000, 10000])
    rmse = 3.0 * lengths[:, None] ** np.array([-0.5, -0.25])[None, :]
    slope, se = _slope_fit(lengths, rmse, 1e-3 * rmse**4)
    np.testing.assert_allclose(slope, [-0.5, -0.25], rtol=1e-12)
    assert np.all(se > 0)


def test_chunking_and_extension_do_not_change_draws(system, design, small_study):
    first = small_study.estimates[:1]
    chunked = _study(system, design, chunk_size=4)  # 2 chunks, the last padded
    # The draws are the same; another vmap batch may round the estimator's sums otherwise.
    np.testing.assert_allclose(chunked.estimates, first, rtol=1e-11, atol=1e-13)
    fewer = _study(system, design, realisations=3, chunk_size=4)
    np.testing.assert_array_equal(fewer.estimates, chunked.estimates[:, :3])
    more = _study(system, design, realisations=9, chunk_size=4)  # 3 chunks on one device
    np.testing.assert_array_equal(more.estimates[:, :6], chunked.estimates)
    legacy = _study(system, design, key=jax.random.PRNGKey(0))
    np.testing.assert_array_equal(legacy.estimates, first)
    without = _study(system, design, keep_estimates=False)
    assert without.estimates is None
    np.testing.assert_array_equal(without.rmse, small_study.rmse[:1])


_DEVICE_SCRIPT = textwrap.dedent("""
    import json, sys, jax, numpy as np, hbjax
    s = hbjax.monte_carlo(hbjax.default_system(), hbjax.default_design(), noise_std=0.2,
                          lengths=[150], realisations=10, key=jax.random.key(3),
                          chunk_size=2, progress=False, keep_estimates=True)
    print()
    json.dump({"devices": len(jax.devices()), "n_devices": s.n_devices,
               "estimates": s.estimates.tobytes().hex(), "rmse": s.rmse.tobytes().hex(),
               "codes": s.codes.tolist()}, sys.stdout)
""")


def _run_devices(count):
    env = dict(os.environ, JAX_ENABLE_X64="1", XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={count}",
               JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", _DEVICE_SCRIPT], env=env, check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def one_device_run():
    return _run_devices(1)


def test_bitwise_identical_on_one_and_four_devices(one_device_run):
    one, four = one_device_run, _run_devices(4)
    assert (one["devices"], four["devices"]) == (1, 4)
    assert (one["n_devices"], four["n_devices"]) == (1, 4)
    assert one["estimates"] == four["estimates"]
    assert one["rmse"] == four["rmse"]
    assert one["codes"] == four["codes"]


def test_failed_realisations_are_counted_and_excluded(system, design):
    def flaky(design, y1, y2, y3):
        res = estimate_giri(design, y1, y2, y3)
        # Fail the realisations whose last noisy y1 sample lies above the offset, with
        # NaN parameters: they must neither abort the study nor reach the statistics.
        bad = y1[-1] > res.offset
        model = jax.tree_util.tree_map(lambda x: jnp.where(bad, jnp.nan, x), res.model)
        return type("R", (), {"model": model, "result": jnp.where(bad, SINGULAR_LS, 0)})()

    s = _study(system, design, estimator=flaky, realisations=12)
    failed = s.codes != 0
    assert failed.any() and (~failed).any()
    np.testing.assert_array_equal(s.n_failed, failed.sum(axis=1))
    np.testing.assert_array_equal(s.n_valid + s.n_failed, [12])
    assert np.all(np.isnan(s.estimates[failed]))
    assert np.all(np.isfinite(s.rmse))
    ok = ~failed[0]
    np.testing.assert_allclose(s.mean[0], s.estimates[0, ok].mean(axis=0), rtol=1e-13)
    msg = hbjax.RESULTS[hbjax.RESULTS.singular_ls]
    np.testing.assert_array_equal(s.failure_counts()[msg], failed.sum(axis=1))
    assert "failed" in s.table(file=open(os.devnull, "w"))


def test_nonfinite_estimate_with_success_code_is_flagged(system, design):
    def nan_model(design, y1, y2, y3):
        res = estimate_giri(design, y1, y2, y3)
        model = jax.tree_util.tree_map(lambda x: x * jnp.nan, res.model)
        return type("R", (), {"model": model, "result": jnp.asarray(0)})()

    s = _study(system, design, estimator=nan_model, realisations=2)
    np.testing.assert_array_equal(s.codes, hbjax._identify.giri.NONFINITE)
    np.testing.assert_array_equal(s.n_valid, [0])
    assert np.all(np.isnan(s.rmse)) and np.all(np.isnan(s.slope))


def test_output_and_callable_noise(system, design):
    out = _study(system, design, noise="output", realisations=3)
    # Output noise: y = simulate(model, v) + e, with the same draws as equation noise.
    n, r = 200, 1
    e = _noise_records(KEY, n, r, 0.1)
    vs = (design.constant_input(n), design.binary_input(n), design.staircase_input(n))
    ys = [hbjax.simulate(system, v) + ei for v, ei in zip(vs, e)]
    # the batched and the eager closed form round differently and its Vandermonde systems
    # amplify rounding (1e-8 relative measured); other draws would differ by about 1e-2
    np.testing.assert_allclose(out.estimates[0, r],
                               hbjax.flatten_params(hbjax.identify_giri(design, *ys).model),
                               rtol=1e-7, atol=1e-12)

    def white(key, length):
        return jax.random.normal(key, (length,), jnp.float32)

    same = _study(system, design, noise=white, realisations=3)
    eq = _study(system, design, realisations=3)
    np.testing.assert_array_equal(same.estimates, eq.estimates)
    assert same.noise == "white"


def test_progress_bar_quiet_when_not_a_terminal(system, design, capsys):
    _study(system, design, realisations=2, progress=True)
    captured = capsys.readouterr()
    assert captured.err == "" and captured.out == ""


def test_table_and_plot(small_study):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hbjax.plot import plot_monte_carlo

    text = small_study.table(file=open(os.devnull, "w"))
    for name in small_study.names:
        assert name in text
    fig = small_study.plot()
    assert len(fig.axes) == 1 + len(small_study.names)
    plt.close(fig)
    fig = plot_monte_carlo(small_study, params=["a1", "c2_0"])
    assert len(fig.axes) == 3
    plt.close(fig)
    # arguments checked before anything is drawn, each named with what it must be
    open_figures = plt.get_fignums()
    for kw, exc, match in [
        (dict(params=["a9"]), ValueError, r"`params` names \['a9'\], not parameters"),
        (dict(params="a1"), TypeError, "`params` must be None or a non-empty list"),
        (dict(length_index=2), ValueError, "`length_index` must index one of the study's 2"),
        (dict(length_index=0.5), TypeError, "`length_index` must be an integer"),
        (dict(bins=0), ValueError, "`bins` must be an integer >= 1"),
        (dict(fig="f"), TypeError, "`fig` must be None or a matplotlib Figure"),
    ]:
        with pytest.raises(exc, match=match):
            plot_monte_carlo(small_study, **kw)
    assert plt.get_fignums() == open_figures


@pytest.mark.parametrize(
    "kw, exc, match",
    [
        (dict(lengths=[0]), ValueError, "lengths"),
        (dict(lengths=[-100]), ValueError, "lengths"),
        (dict(lengths=[100.5]), TypeError, "lengths"),
        (dict(lengths=[]), ValueError, "lengths"),
        (dict(lengths=[17]), ValueError, "one period of v3"),
        (dict(lengths=[200, 200]), ValueError, "distinct"),
        (dict(lengths="200"), TypeError, "lengths"),
        (dict(realisations=0), ValueError, "realisations"),
        (dict(realisations=2.0), TypeError, "realisations"),
        (dict(key=0), TypeError, "PRNG key"),
        (dict(key=np.array([0, 1], np.uint32)), TypeError, "PRNG key"),
        (dict(key=jax.random.split(KEY, 2)), TypeError, "PRNG key"),
        (dict(noise="pink"), ValueError, "noise"),
        (dict(noise=lambda k, n: jnp.zeros(n + 1)), ValueError, r"shape \(200,\)"),
        (dict(noise=lambda k, n: jnp.zeros((n, 2))), ValueError, "noise"),
        (dict(noise_std=-1.0), ValueError, "noise_std"),
        (dict(noise_std="x"), TypeError, "noise_std"),
        (dict(estimator="mle"), ValueError, "estimator"),
        (dict(chunk_size=0), ValueError, "chunk_size"),
        (dict(devices=["cpu"]), TypeError, "devices"),
    ],
)
def test_bad_input(system, design, kw, exc, match):
    opts = dict(noise_std=0.1, lengths=[200], realisations=2, key=KEY, progress=False)
    opts.update(kw)
    with pytest.raises(exc, match=match):
        hbjax.monte_carlo(system, design, **opts)


def test_bad_model_and_design(system, design):
    opts = dict(noise_std=0.1, lengths=[200], realisations=2, key=KEY)
    with pytest.raises(TypeError, match="`model`"):
        hbjax.monte_carlo(system.arx, design, **opts)
    with pytest.raises(TypeError, match="`design`"):
        hbjax.monte_carlo(system, (2, 3, 4.0), **opts)


def _ar1(phi):
    """Unit-variance AR(1) equation error ``e(t) = phi e(t-1) + sqrt(1-phi^2) w(t)``."""

    def noise(key, length):
        w = jax.random.normal(key, (length,)) * jnp.sqrt(1 - phi**2)
        return jax.lax.scan(lambda c, x: (phi * c + x, phi * c + x), 0.0, w)[1]

    return noise


@pytest.mark.slow
def test_consistency_rmse_slopes_near_minus_half(system, design):
    # Propositions 1-2 under A6 (white equation error): RMSE ~ N^-1/2 for every parameter.
    s = hbjax.monte_carlo(system, design, noise_std=0.1, lengths=[1000, 4000, 16000],
                          realisations=300, key=jax.random.key(11), progress=False)
    assert np.all(s.n_valid == 300)
    assert np.all((s.slope >= -0.6) & (s.slope <= -0.4)), dict(zip(s.names, s.slope))
    # ... and the interval of each slope contains -1/2 or lies within the band.
    assert np.all(s.slope_ci[:, 0] < -0.4) and np.all(s.slope_ci[:, 1] > -0.6)


@pytest.mark.slow
@pytest.mark.parametrize("noise", ["output", "ar1"])
def test_broken_a6_bias_does_not_vanish(system, design, noise):
    # Coloured errors in the LS regression (23) make E[phi(t) xi(t)] != 0: the normal
    # equations converge to a biased theta. The bias of a1 stays put while its standard
    # error shrinks, so it becomes many standard errors large.
    s = hbjax.monte_carlo(system, design, noise_std=0.3, lengths=[2000, 16000],
                          realisations=100, key=jax.random.key(5), progress=False,
                          noise=_ar1(0.8) if noise == "ar1" else noise)
    se = s.std / np.sqrt(s.n_valid)[:, None]
    a1 = s.names.index("a1")
    assert abs(s.bias[1, a1]) > 8 * se[1, a1]
    assert abs(s.bias[1, a1]) > 0.5 * abs(s.bias[0, a1])
    assert s.slope[a1] > -0.25


_PROCESS_SCRIPT = textwrap.dedent("""
    import json, sys, jax
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address=sys.argv[1], num_processes=2,
                               process_id=int(sys.argv[2]))
    import hbjax
    s = hbjax.monte_carlo(hbjax.default_system(), hbjax.default_design(), noise_std=0.2,
                          lengths=[150], realisations=10, key=jax.random.key(3),
                          chunk_size=2, progress=False, keep_estimates=True)
    print()
    json.dump({"devices": len(jax.devices()), "estimates": s.estimates.tobytes().hex()},
              sys.stdout)
""")


@pytest.mark.slow
def test_two_processes_with_jax_distributed_match_one_process(one_device_run):
    # The multi-host recipe of docs/monte_carlo.md, on one machine: two processes with one
    # CPU device each form a 2-device mesh and reproduce the single-process numbers.
    import socket

    with socket.socket() as sock:
        sock.bind(("localhost", 0))
        port = sock.getsockname()[1]
    # the suite's compiler flags (tests/conftest.py) as in the one-process run, no device count
    env = dict(os.environ, JAX_ENABLE_X64="1", JAX_PLATFORMS="cpu",
               XLA_FLAGS=" ".join(f for f in os.environ.get("XLA_FLAGS", "").split()
                                  if "device_count" not in f))
    procs = [subprocess.Popen([sys.executable, "-c", _PROCESS_SCRIPT, f"localhost:{port}",
                               str(i)], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for i in range(2)]
    outs = [json.loads(p.communicate(timeout=300)[0].strip().splitlines()[-1]) for p in procs]
    single = one_device_run
    assert [o["devices"] for o in outs] == [2, 2]
    assert outs[0]["estimates"] == outs[1]["estimates"] == single["estimates"]


@pytest.mark.slow
def test_refined_estimator_improves_on_the_closed_form(system, design):
    # Prediction-error refinement (issue 3) started from the closed form is the ML
    # estimator under Gaussian equation error: on the same draws it should beat the
    # (consistent but not efficient) closed form on average over the parameters.
    opts = dict(noise_std=0.1, lengths=[1000], realisations=12, key=jax.random.key(4),
                progress=False)
    refined = hbjax.monte_carlo(system, design, estimator="refined", **opts)
    giri = hbjax.monte_carlo(system, design, **opts)
    assert refined.estimator == "refined" and refined.n_valid[0] >= 10
    ratio = (refined.rmse[0] / giri.rmse[0]) ** 2
    assert np.mean(ratio) < 0.9, dict(zip(refined.names, ratio))


@pytest.mark.slow
def test_refined_estimator_does_not_fail_where_the_closed_form_succeeds(system, design):
    # Short records at high noise: the closed form succeeds on every realisation, and the
    # refinement from it must too (the labelled solve alone ended at 8 times the start's
    # prediction error, refused as no input effect, in 7 of 16 of these realisations).
    opts = dict(noise_std=0.3, lengths=[200], realisations=12, key=jax.random.key(0),
                progress=False)
    giri = hbjax.monte_carlo(system, design, **opts)
    refined = hbjax.monte_carlo(system, design, estimator="refined", **opts)
    assert giri.n_failed[0] == 0
    assert refined.n_failed[0] == 0, refined.failure_counts()


def test_the_means_interval_covers_at_its_level_with_few_realisations():
    # Over 400 studies of 3 unbiased realisations the "95% interval" must cover the true
    # value about 95 % of the time (1.96 standard errors covered 84 %).
    import re

    system, design = hbjax.default_system(), hbjax.default_design()
    names = hbjax.param_names(system)
    true = np.asarray(hbjax.flatten_params(hbjax.normalise(system, design.h_m)))
    fixed = dict(compile_seconds=np.zeros(1), run_seconds=np.zeros(1), realisations=3,
                 noise_std=0.1, estimator="x", noise="equation", n_devices=1, chunk_size=2)
    rng = np.random.default_rng(0)
    hits, trials = 0, 400
    for _ in range(trials):
        est = true + 0.01 * rng.normal(size=(1, 3, true.size))
        study = hbjax.Study.from_estimates([1000], names, true, est, np.zeros((1, 3), int),
                                           keep_estimates=True, **fixed)
        line = next(ln for ln in str(study.summary()).splitlines() if ln.startswith("a1 "))
        lo, hi = map(float, re.search(r"\[([-\d.e+]+), ([-\d.e+]+)\]", line).groups())
        hits += lo <= true[0] <= hi
    # binomial(400, 0.95): sd 1.1 %; 0.84 lies 10 sd below
    assert 0.91 <= hits / trials <= 0.99, hits / trials


def test_an_rbg_key_is_refused_naming_key(system, design):
    with pytest.raises(ValueError, match="`key` must be a threefry2x32 key"):
        _study(system, design, key=jax.random.key(3, impl="rbg"))


@pytest.mark.parametrize("realisations", [1, 3])
def test_draws_that_do_not_differ_give_no_slope_interval(realisations):
    """One draw per length, or several identical ones (no noise: every draw the same
    record), measure no Monte Carlo uncertainty: the slope is the plain fit and its
    interval NaN (it was a zero-width interval: an infinite weight)."""
    rng = np.random.default_rng(0)
    true = np.array([0.5, 2.0])
    lengths = [100, 400, 1600]
    one = true + rng.standard_normal((3, 1, 2)) / np.sqrt(np.array(lengths))[:, None, None]
    est = np.repeat(one, realisations, axis=1)
    study = hbjax.Study.from_estimates(
        lengths, ["a1", "b1"], true, est, np.zeros((3, realisations), int),
        keep_estimates=False, compile_seconds=np.zeros(3), run_seconds=np.zeros(3),
        realisations=realisations, noise_std=0.1 if realisations == 1 else 0.0,
        estimator="giri", noise="white", n_devices=1, chunk_size=1)
    rmse = np.abs(one[:, 0, :] - true)
    expected = [np.polyfit(np.log(lengths), np.log(rmse[:, p]), 1)[0] for p in range(2)]
    np.testing.assert_allclose(study.slope, expected, rtol=1e-12)
    assert np.all(np.isnan(study.slope_stderr)) and np.all(np.isnan(study.slope_ci))
    assert np.all(np.isnan(study.std)) == (realisations == 1)
