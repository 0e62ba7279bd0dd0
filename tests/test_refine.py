"""Refinement (issue 3): kernels, gauge, refine, separable LS, bad input, statistics."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hbjax
from hbjax._identify import criteria as C
from hbjax._identify import parametrisation as P
from hbjax._core.model import play_trajectory
from hbjax._identify.refine import RESULTS, refine_batch, refine_traceable

from conftest import reference_simulate

N_PAPER = 2000
SIGMA = 0.2


def paper_records(system, design, n, key, sigma=SIGMA, output_noise=False):
    vs = [design.constant_input(n), design.binary_input(n), design.staircase_input(n)]
    recs = []
    for v, k in zip(vs, jax.random.split(key, 3)):
        e = sigma * jax.random.normal(k, (n,))
        if output_noise:
            y = hbjax.simulate(system, v) + e
        else:
            y = hbjax.simulate(system, v, e)
        recs.append((v, np.asarray(y)))
    return recs


@pytest.fixture(scope="module")
def paper():
    system, design = hbjax.default_system(), hbjax.default_design()
    recs = paper_records(system, design, N_PAPER, jax.random.PRNGKey(0))
    giri = hbjax.identify_giri(design, *[y for _, y in recs])
    truth = hbjax.normalise(system, design.h_m)
    refined = hbjax.refine(giri.model, recs, h_m=design.h_m)
    return dict(system=system, design=design, recs=recs, giri=giri, truth=truth, refined=refined)


def row(batched_result, i):
    """Flattened parameters of realisation ``i`` of a batched result."""
    return np.asarray(hbjax.flatten_params(
        jax.tree_util.tree_map(lambda x: x[i], batched_result.model)))


def random_input(rng, n, amplitude=8.0, max_hold=20):
    levels = rng.uniform(-amplitude, amplitude, n)
    return np.repeat(levels, rng.integers(1, max_hold, n))[:n]


# ----------------------------------------------------------------------------- kernels
def test_play_sources_hand_case():
    # band [0, 1] then [2, 3] then [-1, 0.5] then [0, 4]: u = 0 (u(-1)=0 inside), 2, 0.5, 0.5
    low = jnp.array([0.0, 2.0, -1.0, 0.0])
    high = jnp.array([1.0, 3.0, 0.5, 4.0])
    u, src = C.play_sources(low, high)
    np.testing.assert_array_equal(np.asarray(u), [0.0, 2.0, 0.5, 0.5])
    # still u(-1); low(1); high(2) -> 4 + 2; kept
    np.testing.assert_array_equal(np.asarray(src), [-1, 1, 6, 6])


def test_inverted_band_rule_hand_case():
    # P1 lower by label; at t = 1, 2, 3 the band is inverted (low > high): the input rose
    # (P1, the low label), fell (P2, the high label), then stayed (hold).
    low = jnp.array([0.0, 3.0, 3.0, 3.0, 0.0])
    high = jnp.array([1.0, 2.0, 2.0, 2.0, 4.0])
    x = jnp.array([0.0, 1.0, 0.5, 0.5, 0.5])
    force = C.inverted_band_rule(low, high, x, jnp.asarray(True))
    np.testing.assert_array_equal(np.asarray(force), [-1, 0, 1, 2, -1])
    u, src = C.play_sources(low, high, force)
    np.testing.assert_array_equal(np.asarray(u), [0.0, 3.0, 2.0, 2.0, 2.0])
    np.testing.assert_array_equal(np.asarray(src), [-1, 1, 7, 7, 7])


def test_kernels_match_core_and_numpy(system):
    rng = np.random.default_rng(1)
    v = random_input(rng, 300)
    xi = 0.1 * rng.normal(size=300)
    y_ref, u_ref = reference_simulate(system.backlash.c1, system.backlash.c2, system.arx.a,
                                      system.arx.b, v, xi)
    p1, p2 = system.backlash.p1(jnp.asarray(v)), system.backlash.p2(jnp.asarray(v))
    u, _ = C.play_sources(jnp.minimum(p1, p2), jnp.maximum(p1, p2))
    np.testing.assert_allclose(u, u_ref, atol=1e-12)
    np.testing.assert_allclose(u, play_trajectory(system.backlash, jnp.asarray(v), 0.0), atol=1e-13)
    y_hat = C.record_outputs(system, jnp.asarray(v), jnp.asarray(y_ref), "prediction")
    np.testing.assert_allclose(y_ref - y_hat, xi, atol=1e-10)
    y_free, _ = reference_simulate(system.backlash.c1, system.backlash.c2, system.arx.a,
                                   system.arx.b, v, np.zeros(300))
    y_sim = C.record_outputs(system, jnp.asarray(v), jnp.asarray(y_ref), "simulation")
    np.testing.assert_allclose(y_sim, y_free, atol=1e-10)


@pytest.mark.parametrize("criterion", ["prediction", "simulation"])
def test_closed_form_jacobian_matches_autodiff_of_core(system, criterion):
    # A continuous input (no ties between consecutive band edges, where the derivative
    # with respect to v is one-sided) so that every derivative is classical.
    rng = np.random.default_rng(2)
    n = 200
    v = np.cumsum(rng.normal(size=n)) * 0.5 + rng.normal(size=n)
    v = jnp.asarray(8 * v / np.abs(v).max())
    y = hbjax.simulate(system, v, 0.2 * jnp.asarray(rng.normal(size=n)))
    theta = hbjax.flatten_params(system)

    def ours(th, v, y):
        return C.record_residual(th, v, y, jnp.asarray(True), 2, 2, criterion)

    def core(th, v, y):
        model = hbjax.unflatten_params(system, th)
        if criterion == "prediction":
            return y - model.predict_trajectory(v, y, 0.0)
        return y - model.simulate_trajectory(v, jnp.zeros_like(v), 0.0)

    np.testing.assert_allclose(jax.jit(jax.jacfwd(ours))(theta, v, y),
                               jax.jit(jax.jacfwd(core))(theta, v, y), atol=1e-9)
    # JVPs with respect to the data (v and y together) against the core's.
    dv, dy = jnp.asarray(rng.normal(size=n)), jnp.asarray(rng.normal(size=n))
    _, t_ours = jax.jit(lambda *a: jax.jvp(lambda v, y: ours(theta, v, y), a[:2], a[2:]))(
        v, y, dv, dy)
    _, t_core = jax.jit(lambda *a: jax.jvp(lambda v, y: core(theta, v, y), a[:2], a[2:]))(
        v, y, dv, dy)
    np.testing.assert_allclose(t_ours, t_core, atol=1e-9)
    loss = lambda f: jax.jit(jax.grad(lambda th: jnp.sum(f(th, v, y) ** 2)))(theta)  # noqa: E731
    np.testing.assert_allclose(loss(ours), loss(core), rtol=1e-9)
    # JVP against central finite differences.
    d = jnp.asarray(rng.normal(size=theta.shape))
    _, tangent = jax.jit(lambda th, d: jax.jvp(lambda t: ours(t, v, y), (th,), (d,)))(theta, d)
    h = 1e-6
    f = jax.jit(ours)
    fd = (f(theta + h * d, v, y) - f(theta - h * d, v, y)) / (2 * h)
    np.testing.assert_allclose(tangent, fd, atol=1e-5)


@pytest.mark.parametrize("h_m", [4.0, None])
def test_parametrisation_satisfies_constraint(h_m):
    gauge = P.PAPER if h_m is not None else P.STATIC_GAIN
    par = P.Parametrisation(2, 2, 3, gauge, jnp.asarray(8.0), jnp.asarray(h_m or 0.0),
                            jnp.asarray(True))
    z = jnp.asarray(np.random.default_rng(3).normal(size=9))
    theta = par.theta(z)
    assert float(par.constraint_row() @ theta) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(par.free(theta), z, atol=1e-12)
    model = par.model(z)
    if h_m is None:
        assert float(jnp.sum(model.arx.b)) == pytest.approx(1.0)
    else:
        gap = model.backlash.p2(-h_m) - model.backlash.p1(h_m)
        assert float(gap) == pytest.approx(1.0)


# ----------------------------------------------------------------------------- refine
def test_refine_paper_experiments(paper):
    res = paper["refined"]
    assert res.result == RESULTS.successful and res.message == "success"
    truth = np.asarray(hbjax.flatten_params(paper["truth"]))
    est = np.asarray(hbjax.flatten_params(res.model))
    std = np.asarray(res.std)
    assert np.all(np.abs(est - truth) < 4.5 * std)
    # the constraint holds and its direction has no variance
    g = hbjax.crlb(paper["truth"], paper["recs"], noise_std=SIGMA, h_m=4.0).constraint
    assert float(g @ est) == pytest.approx(1.0, abs=1e-10)
    np.testing.assert_allclose(res.covariance @ g, 0.0, atol=1e-12)
    assert float(res.noise_std) == pytest.approx(SIGMA, rel=0.05)
    assert int(res.stats["samples"]) == 3 * N_PAPER
    assert float(res.stats["cost"]) <= float(res.stats["initial_cost"])
    assert not bool(res.branches_cross)


def test_refine_lowers_cost_to_the_same_optimum_from_elsewhere(paper):
    start = hbjax.unflatten_params(
        paper["truth"], hbjax.flatten_params(paper["truth"]) * 1.05 + 0.01)
    other = hbjax.refine(start, paper["recs"], h_m=4.0)
    np.testing.assert_allclose(hbjax.flatten_params(other.model),
                               hbjax.flatten_params(paper["refined"].model), rtol=1e-6, atol=1e-8)


def test_gauges_describe_the_same_model(paper):
    static = hbjax.refine(paper["giri"].model, paper["recs"])
    assert float(jnp.sum(static.model.arx.b)) == pytest.approx(1.0)
    back = hbjax.normalise(static.model, 4.0)
    np.testing.assert_allclose(hbjax.flatten_params(back),
                               hbjax.flatten_params(paper["refined"].model), rtol=1e-6, atol=1e-8)
    truth = hbjax.normalise_static_gain(paper["system"])
    v, y = paper["recs"][1]
    np.testing.assert_allclose(hbjax.predict(truth, v, y), hbjax.predict(paper["system"], v, y),
                               atol=1e-10)


def test_refine_matches_scipy_least_squares(paper):
    # Peer: scipy's MINPACK Levenberg-Marquardt with finite differences on a plain NumPy
    # residual (short records: the loop is pure Python).
    from scipy.optimize import least_squares

    n = 120
    recs = paper_records(paper["system"], paper["design"], n, jax.random.PRNGKey(5))
    giri = hbjax.identify_giri(paper["design"], *[y for _, y in recs])
    h = 4.0

    def theta_of(z):
        th = np.insert(z, 7, 0.0)
        k = np.arange(3)
        g = np.concatenate([np.zeros(4), -(h**k), (-h) ** k])
        th[7] = 1.0 - g @ th
        return th

    def fun(z):
        th = theta_of(z)
        out = []
        for v, y in recs:
            _, u = reference_simulate(th[4:7], th[7:], [0.0], [0.0], v, np.zeros(n))
            pred = np.zeros(n)
            pred[1:] += -th[0] * y[:-1] + th[2] * u[:-1]
            pred[2:] += -th[1] * y[:-2] + th[3] * u[:-2]
            out.append(y - pred)
        return np.concatenate(out)

    z0 = np.delete(np.asarray(hbjax.flatten_params(giri.model)), 7)
    peer = theta_of(least_squares(fun, z0, method="lm", xtol=1e-12, ftol=1e-12).x)
    ours = hbjax.refine(giri.model, recs, h_m=h, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(hbjax.flatten_params(ours.model), peer,
                               rtol=1e-6, atol=1e-6 * np.abs(peer).max())


def test_refine_batch_equals_single_fits(paper):
    design, system = paper["design"], paper["system"]
    records = [paper_records(system, design, N_PAPER, k) for k in jax.random.split(
        jax.random.PRNGKey(9), 2)]
    models = [hbjax.identify_giri(design, *[y for _, y in r]).model for r in records]
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *models)
    inputs = tuple(jnp.asarray(v) for v, _ in records[0])
    outputs = tuple(jnp.stack([jnp.asarray(r[k][1]) for r in records]) for k in range(3))
    batch = refine_batch(stacked, inputs, outputs, h_m=4.0)
    # the traceable core under vmap, with a third start whose normalisation is undefined
    # (mu = 0): it is reported in `.result`, the others are unaffected.
    flat = hbjax.Hammerstein(hbjax.Backlash([0.0, 1.0, 0.0], [8.0, 1.0, 0.0]), models[0].arx)
    with_bad = jax.tree_util.tree_map(lambda x, y: jnp.concatenate([x, y[None]]), stacked, flat)
    vmapped = jax.jit(jax.vmap(lambda m, y1, y2, y3: refine_traceable(
        m, tuple(zip(inputs, (y1, y2, y3))), h_m=4.0)))(
        with_bad, *[jnp.concatenate([o, o[:1]]) for o in outputs])
    assert int(vmapped.result._value[2]) == RESULTS.gauge_undefined._value
    assert np.all(np.isfinite(row(vmapped, 2)))
    for i, r in enumerate(records):
        single = hbjax.refine(models[i], r, h_m=4.0, throw=False)
        for res in (batch, vmapped):  # noqa: B007
            np.testing.assert_allclose(row(res, i), hbjax.flatten_params(single.model),
                                       rtol=1e-7, atol=1e-9)
    assert np.all(np.asarray(batch.result._value) == np.asarray(vmapped.result._value)[:2])


def test_simulation_criterion_on_equation_error_data_is_close(paper):
    sim = hbjax.refine(paper["giri"].model, paper["recs"], h_m=4.0, criterion="simulation")
    assert sim.criterion == "simulation" and sim.result == RESULTS.successful
    truth = np.asarray(hbjax.flatten_params(paper["truth"]))
    assert np.max(np.abs(np.asarray(hbjax.flatten_params(sim.model)) - truth)) < 0.1


def test_separable_ls_reaches_the_refined_optimum(paper):
    sep = hbjax.separable_ls(paper["giri"].model, paper["recs"], h_m=4.0)
    assert sep.result == RESULTS.successful
    np.testing.assert_allclose(hbjax.flatten_params(sep.model),
                               hbjax.flatten_params(paper["refined"].model), rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(sep.covariance, paper["refined"].covariance, rtol=1e-4, atol=1e-12)


# ----------------------------------------------------------------------------- bad input
def test_bad_input(paper):
    model, recs = paper["giri"].model, paper["recs"]
    v, y = recs[0]
    with pytest.raises(ValueError, match="equal lengths"):
        hbjax.refine(model, (v, y[:-1]), h_m=4.0)
    y_bad = y.copy()
    y_bad[7] = np.nan
    with pytest.raises(ValueError, match="NaN or inf"):
        hbjax.refine(model, [(v, y_bad)] + recs[1:], h_m=4.0)
    with pytest.raises(ValueError, match="criterion"):
        hbjax.refine(model, recs, criterion="bogus")
    with pytest.raises(TypeError, match="Hammerstein"):
        hbjax.refine(model.backlash, recs)
    with pytest.raises(TypeError, match="pair"):
        hbjax.refine(model, [recs[0], "nope"])
    batched = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), model)
    with pytest.raises(ValueError, match="single model"):
        hbjax.refine(batched, recs)
    # mu = P2(-h_m) - P1(h_m) = 0: the paper's normalisation cannot be applied
    flat = hbjax.Hammerstein(hbjax.Backlash([0.0, 1.0, 0.0], [8.0, 1.0, 0.0]), model.arx)
    with pytest.raises(ValueError, match="mu"):
        hbjax.refine(flat, recs, h_m=4.0)
    zero_gain = hbjax.Hammerstein(model.backlash, hbjax.ARX(model.arx.a, [1.0, -1.0]))
    with pytest.raises(ValueError, match="B\\(1\\)"):
        hbjax.refine(zero_gain, recs)
    with pytest.raises(ValueError, match="h_m"):
        hbjax.refine(model, recs, h_m=-1.0)
    with pytest.raises(ValueError, match="samples"):
        hbjax.refine(model, (v[:4], y[:4]), h_m=4.0)


def test_non_convergence_is_reported(paper):
    start = hbjax.unflatten_params(paper["truth"], hbjax.flatten_params(paper["truth"]) * 1.3)
    # (restarts=0: the verdict of this refinement, not of a multi-start fit's)
    with pytest.raises(hbjax.RefinementError, match="did not converge"):
        hbjax.refine(start, paper["recs"], h_m=4.0, max_steps=2, restarts=0)
    res = hbjax.refine(start, paper["recs"], h_m=4.0, max_steps=2, restarts=0, throw=False)
    assert res.result == RESULTS.nonlinear_max_steps_reached
    assert "maximum number of steps" in res.message
    assert int(res.stats["steps"]) == 2


def _free_start(recs, start, h_m=4.0):
    import equinox as eqx
    from hbjax._identify.refine import gauge_transform, make_parametrisation

    par = make_parametrisation(start, recs, h_m)
    model, _ = gauge_transform(start, par)
    par = eqx.tree_at(lambda p: p.lower_is_p1, par, C.lower_is_p1(model, recs))
    return par, par.free(hbjax.flatten_params(model))


def test_sufficient_statistics_reproduce_the_full_residual(paper):
    """``w^T (M^T M) w`` is the sum of squared prediction errors and ``D^T M^T M D`` the
    Gauss-Newton matrix of the full residual, at a point away from the optimum."""
    from hbjax._identify import sufficient as S

    recs = tuple((jnp.asarray(v), jnp.asarray(y)) for v, y in paper["recs"])
    start = hbjax.unflatten_params(paper["truth"], hbjax.flatten_params(paper["truth"]) * 1.1)
    par, z = _free_start(recs, start)
    gram, _, ssr = S.statistics(z, par, recs)
    flat = lambda zz: jnp.concatenate(C.residuals(zz, par, recs, "prediction"))  # noqa: E731
    r, jac = flat(z), jax.jacfwd(flat)(z)
    assert float(ssr) == pytest.approx(float(r @ r), rel=1e-12)
    w = S.bilinear_weights(z, par)
    assert float(w @ gram @ w) == pytest.approx(float(r @ r), rel=1e-10)
    jtj = jac.T @ jac
    np.testing.assert_allclose(S.gauss_newton_matrix(z, par, gram), jtj, rtol=1e-9,
                               atol=1e-9 * float(jnp.max(jnp.abs(jtj))))
    f = S.gram_factor(gram)
    np.testing.assert_allclose(f.T @ f, gram, rtol=1e-9, atol=1e-9 * float(jnp.max(gram)))


def test_statistics_path_reports_the_cost_of_low_noise_data(paper):
    """``w^T (M^T M) w`` cancels ``||y||^2`` against the fit: the reported cost, noise level
    and covariance come from the residual itself, so they stay right when the noise is tiny."""
    design, system = paper["design"], paper["system"]
    recs = tuple((jnp.asarray(v), jnp.asarray(y)) for v, y in
                 paper_records(system, design, N_PAPER, jax.random.PRNGKey(8), sigma=1e-8))
    start = hbjax.unflatten_params(paper["truth"], hbjax.flatten_params(paper["truth"]) * 1.05)
    fast = refine_traceable(start, recs, h_m=4.0)
    full = refine_traceable(start, recs, h_m=4.0, statistics=False)
    assert fast.result == RESULTS.successful
    assert float(fast.stats["cost"]) == pytest.approx(float(full.stats["cost"]), rel=1e-6)
    assert float(fast.noise_std) == pytest.approx(1e-8, rel=0.05)
    np.testing.assert_allclose(fast.std, full.std, rtol=1e-4)


@pytest.mark.parametrize("max_rounds", [None, 1])
def test_statistics_path_and_its_fallback_match_the_full_solve(paper, monkeypatch, max_rounds):
    """Rounds on the Gram matrix reach the full solve's optimum; when the play operator's
    sources have not settled after the allowed rounds, the full solve finishes from there
    and reaches it too."""
    from hbjax._identify import sufficient as S

    if max_rounds is not None:
        monkeypatch.setattr(S, "MAX_ROUNDS", max_rounds)
    # A smooth input: where the output leaves the band edge at a turning point depends on
    # the band, so a start with a narrower band has other sources than the optimum.
    t = np.arange(N_PAPER)
    v = 6 * np.sin(2 * np.pi * t / 97) + 2 * np.sin(2 * np.pi * t / 31)
    y = hbjax.simulate(paper["system"], v, SIGMA * jax.random.normal(jax.random.PRNGKey(5), t.shape))
    recs = ((jnp.asarray(v), jnp.asarray(y)),)
    theta = np.array(hbjax.flatten_params(paper["truth"]))
    theta[4] -= 0.05  # lower P1 and raise P2 by 0.05: another band width
    theta[7] += 0.05
    start = hbjax.unflatten_params(paper["truth"], jnp.asarray(theta))
    par, z0 = _free_start(recs, start)
    *_, unsettled, _ = S.solve_by_statistics(par, z0, recs, max_steps=256, rtol=1e-7,
                                             atol=1e-7)
    assert bool(unsettled) == (max_rounds == 1)  # which path the comparison exercises
    fast = refine_traceable(start, recs, h_m=4.0)
    full = refine_traceable(start, recs, h_m=4.0, statistics=False)
    assert fast.result == RESULTS.successful and full.result == RESULTS.successful
    np.testing.assert_allclose(hbjax.flatten_params(fast.model),
                               hbjax.flatten_params(full.model), rtol=1e-7, atol=1e-9)
    assert float(fast.stats["cost"]) == pytest.approx(float(full.stats["cost"]), rel=1e-9)
    assert float(fast.stats["initial_cost"]) == pytest.approx(
        float(full.stats["initial_cost"]), rel=1e-9)
    np.testing.assert_allclose(fast.covariance, full.covariance, rtol=1e-5,
                               atol=1e-8 * float(jnp.max(full.covariance)))


def test_start_with_crossed_branches_reaches_the_optimum(paper):
    """The paper's closed form's inactive branch, extrapolated to the outer staircase
    levels, often dips through the active one (the closed form now holds it to a band at
    the design's inputs); refining from the closed form must reach an optimum as good as
    refining from the truth: the same cost up to a small fraction of sigma^2 per sample
    (the extrapolated coefficients are weakly determined, so the points may differ)."""
    design, system = paper["design"], paper["system"]
    for k in jax.random.split(jax.random.PRNGKey(21), 4):
        recs = paper_records(system, design, N_PAPER, k)
        giri = hbjax.identify_giri(design, *[y for _, y in recs])
        a = hbjax.refine(giri.model, recs, h_m=4.0, throw=False)
        b = hbjax.refine(paper["truth"], recs, h_m=4.0, throw=False)
        assert a.result == RESULTS.successful and b.result == RESULTS.successful
        assert float(a.stats["cost"]) <= float(b.stats["cost"]) * (1 + 1e-3)


# ----------------------------------------------------------------------------- statistics
@pytest.mark.slow
def test_output_error_noise_bias_and_consistency():
    """White noise on y (not on the equation): the closed form and the prediction-error
    criterion are biased (the regressors contain the noise), output error is consistent."""
    system, design = hbjax.default_system(), hbjax.default_design()
    n, reps, sigma = 4000, 24, 0.3
    truth = np.asarray(hbjax.flatten_params(hbjax.normalise(system, design.h_m)))
    est = {"giri": [], "prediction": [], "simulation": []}
    inputs = tuple(jnp.asarray(v) for v in (design.constant_input(n), design.binary_input(n),
                                            design.staircase_input(n)))
    ys, giri = [], []
    for k in jax.random.split(jax.random.PRNGKey(11), reps):
        recs = paper_records(system, design, n, k, sigma=sigma, output_noise=True)
        g = hbjax.identify_giri(design, *[y for _, y in recs], throw=False)
        ys.append([y for _, y in recs])
        giri.append(g.model)
        est["giri"].append(np.asarray(hbjax.flatten_params(g.model)))
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *giri)
    outputs = tuple(jnp.stack([jnp.asarray(y[k]) for y in ys]) for k in range(3))
    for crit in ("prediction", "simulation"):
        res = refine_batch(stacked, inputs, outputs, h_m=design.h_m, criterion=crit)
        ok = np.asarray(res.result._value) == 0
        assert ok.mean() >= 0.9
        est[crit] = np.stack([row(res, i) for i in range(reps) if ok[i]])
    z = {}
    for name, e in est.items():
        e = np.asarray(e)
        z[name] = (e.mean(0) - truth) / (e.std(0, ddof=1) / np.sqrt(len(e)))
    # a1, a2 are pulled towards zero by the noise in the regressors
    assert np.max(np.abs(z["prediction"][:2])) > 8
    assert np.max(np.abs(z["giri"][:2])) > 8
    assert np.max(np.abs(z["simulation"])) < 4


@pytest.mark.slow
def test_refined_estimator_reaches_the_cramer_rao_bound():
    """Paper's three experiments, n = 2, m = 3, equation-error noise, N = 10^4 per
    experiment, 500 realisations: var(refined) / CRLB <= 1.2 and |bias| <= 0.1 std for
    every normalised parameter; the closed form sits well above the bound."""
    from hbjax._identify.giri import estimate_giri

    system, design = hbjax.default_system(), hbjax.default_design()
    n, reps, chunk, sigma = 10_000, 500, 100, 0.2
    inputs = tuple(jnp.asarray(v) for v in (design.constant_input(n), design.binary_input(n),
                                            design.staircase_input(n)))

    @jax.jit
    def study(keys):
        def simulate(k):
            return tuple(system.simulate_trajectory(v, sigma * jax.random.normal(kk, (n,)), 0.0)
                         for v, kk in zip(inputs, jax.random.split(k, 3)))

        ys = jax.vmap(simulate)(keys)
        giri = jax.vmap(lambda *y: estimate_giri(design, *y))(*ys)
        ref = refine_batch(giri.model, inputs, ys, h_m=design.h_m, max_steps=100)
        flat = jax.vmap(hbjax.flatten_params)
        return flat(giri.model), flat(ref.model), ref.result._value, ys

    keys = jax.random.split(jax.random.PRNGKey(42), reps)
    parts = [study(keys[i:i + chunk]) for i in range(0, reps, chunk)]
    giri = np.concatenate([p[0] for p in parts])
    refined = np.concatenate([p[1] for p in parts])
    codes = np.concatenate([p[2] for p in parts])
    truth_model = hbjax.normalise(system, design.h_m)
    truth = np.asarray(hbjax.flatten_params(truth_model))
    ys = [p[3] for p in parts][0]
    bound = hbjax.crlb(truth_model, list(zip(inputs, [y[0] for y in ys])), noise_std=sigma,
                       h_m=design.h_m)
    var_bound = np.diag(np.asarray(bound.covariance))
    # Realisations whose refined branches cross at a recorded input are failures (reported
    # with a code): about 1 % here, from the extrapolated inactive branch at -2h_m + h_m/m.
    ok = codes == 0
    assert np.all((codes == 0) | (codes == RESULTS.branches_cross._value))
    assert ok.mean() >= 0.97
    est = refined[ok]
    ratio = est.var(0, ddof=1) / var_bound
    bias = (est.mean(0) - truth) / est.std(0, ddof=1)
    assert np.all(ratio <= 1.2), ratio
    assert np.all(np.abs(bias) <= 0.1), bias
    giri_ratio = giri.var(0, ddof=1) / var_bound
    assert np.all(giri_ratio >= 1.5), giri_ratio
