"""Record lengths as runtime values in `refine`: an eager call pads every record to its
length's bucket and masks the padded samples out of the residuals, their Jacobian, the
Gram matrix, the band checks, the sample count and the quality figures, so that

- its results equal those of the unpadded records (under `jax.jit` nothing is padded: the
  reference), for both criteria, one or several records;
- a new length in a bucket already compiled compiles no new refinement program.

No timings here: benchmarks/cold_start.py."""

import jax
import jax.monitoring
import numpy as np
import pytest

import hbjax


def _record(n, seed, noise=0.1):
    rng = np.random.default_rng(seed)
    v = np.repeat(rng.uniform(-8, 8, n), rng.integers(1, 20, n))[:n]
    y = hbjax.simulate(hbjax.default_system(), v, noise * rng.standard_normal(n))
    return v, np.asarray(y)


def _start():
    return jax.tree_util.tree_map(lambda x: 1.1 * x, hbjax.default_system())


def _relative(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    finite = np.isfinite(b)
    assert np.array_equal(np.isfinite(a), finite)
    scale = max(float(np.max(np.abs(b[finite]), initial=0.0)), 1e-300)
    return float(np.max(np.abs(a[finite] - b[finite]), initial=0.0)) / scale


@pytest.mark.parametrize("criterion,lengths", [
    ("prediction", (300,)), ("prediction", (317,)), ("prediction", (290, 450)),
    ("simulation", (300,)), ("simulation", (317,)),
])
def test_padded_refine_equals_unpadded(criterion, lengths):
    recs = [_record(n, seed=n) for n in lengths]
    init = _start()
    padded = hbjax.refine(init, recs, criterion=criterion, throw=False)

    @jax.jit
    def unpadded(recs):  # traced records are never padded
        return hbjax.refine(init, recs, criterion=criterion, throw=False)

    ref = unpadded(recs)
    assert ref.result == padded.result == hbjax.RESULTS.successful
    # Sums of squares, noise level and fits: rounding of a sum in another order.
    for key in ("cost", "initial_cost"):
        assert _relative(padded.stats[key], ref.stats[key]) < 1e-12
    assert int(padded.stats["samples"]) == int(ref.stats["samples"]) == sum(lengths)
    assert _relative(padded.noise_std, ref.noise_std) < 1e-12
    assert _relative(padded.sim_fit, ref.sim_fit) < 1e-12
    assert _relative(padded.sim_fit_pooled, ref.sim_fit_pooled) < 1e-12
    assert padded.sim_fit.shape == (len(lengths),)
    # Parameters: the optimum is fixed by the data only up to cond(J) * eps; the
    # Levenberg-Marquardt stopping test on rounding-level differences may stop steps
    # earlier or later (measured 8 against 18 steps, 1.9e-10 norm-wise relative, with the
    # suite's compiler flags), so the two are compared in standard errors: measured at
    # most 6.5e-8, against the 1e-6 allowed.
    theta, theta_ref = hbjax.flatten_params(padded.model), hbjax.flatten_params(ref.model)
    std = np.asarray(ref.std)
    assert np.all(np.isfinite(std) & (std > 0))
    assert np.max(np.abs(np.asarray(theta - theta_ref)) / std) < 1e-6
    assert _relative(padded.covariance, ref.covariance) < 1e-9
    # Discrete and range fields: exactly equal.
    for field in ("branches_cross", "stable", "identified", "core_finish"):
        np.testing.assert_array_equal(getattr(padded, field), getattr(ref, field))
    np.testing.assert_array_equal(padded.data_range, ref.data_range)
    np.testing.assert_array_equal(padded.active_ranges, ref.active_ranges)
    # The padding (zeros) lies inside the data range here; a masked range ignores it.
    v_all = np.concatenate([v for v, _ in recs])
    np.testing.assert_array_equal(padded.data_range, [v_all.min(), v_all.max()])


def test_new_length_in_a_compiled_bucket_compiles_no_refinement():
    compiled = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/jaxpr_trace_duration":
            compiled.append(str(kwargs.get("fun_name", "")))

    init = _start()
    # max_steps=17: a program no other test compiles, so the first call must trace it.
    recs = {n: _record(n, seed=n) for n in (300, 311)}
    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        hbjax.refine(init, recs[300], criterion="simulation", max_steps=17, throw=False)
        first = list(compiled)
        compiled.clear()
        res = hbjax.refine(init, recs[311], criterion="simulation", max_steps=17,
                           throw=False)
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert any("refine" in name for name in first), first  # the listener sees compiles
    assert not any("refine" in name for name in compiled), compiled
    assert int(res.stats["samples"]) == 311
