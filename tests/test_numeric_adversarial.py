"""Numerical adversarial cases: no stale compiled study, the same bits on any device count
and study size, no complex input cast to its real part, no silent inf/NaN, data far from
unit scale handled or refused clearly, result codes that cannot wrap to success.
(``docs/robustness.md`` documents the behaviour each test pins down.)"""

import json
import os
import re
import subprocess
import sys
import textwrap
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hbjax


M = hbjax.default_system()
D = hbjax.default_design()
MN = hbjax.normalise(M, D.h_m)
MC = dict(noise_std=0.1, lengths=[40], realisations=4, key=jax.random.key(0), progress=False,
          keep_estimates=True)


def _constant_estimate(shift):
    """A traceable estimator returning the true normalised model shifted by ``shift()``."""
    def estimator(design, y1, y2, y3):
        model = jax.tree_util.tree_map(lambda x: x + shift(), MN)
        return types.SimpleNamespace(model=model, result=0)
    return estimator


# ----------------------------------------------------------------------------- Monte Carlo


class _Shifted:
    shift = 0.0

    def estimate(self, design, y1, y2, y3):
        return _constant_estimate(lambda: self.shift)(design, y1, y2, y3)


_GLOBAL_SCALE = 1.0


def _global_noise(key, length):
    return _GLOBAL_SCALE * jax.random.normal(key, (length,))


def test_monte_carlo_retraces_user_callables_every_call():
    global _GLOBAL_SCALE
    obj = _Shifted()
    first = hbjax.monte_carlo(M, D, estimator=obj.estimate, **MC).estimates
    obj.shift = 1.0  # the same bound method (equal, and hashing equal) reads new state
    second = hbjax.monte_carlo(M, D, estimator=obj.estimate, **MC).estimates
    np.testing.assert_allclose(second - first, 1.0, rtol=0, atol=1e-12)

    opts = dict(MC, lengths=[200], keep_estimates=False)
    try:
        quiet = hbjax.monte_carlo(M, D, noise=_global_noise, **opts)
        _GLOBAL_SCALE = 50.0  # a global the noise callable reads
        loud = hbjax.monte_carlo(M, D, noise=_global_noise, **opts)
    finally:
        _GLOBAL_SCALE = 1.0
    assert np.all(loud.rmse > 5 * quiet.rmse)


@pytest.mark.parametrize("code, expect", [(2**40, 2**31 - 1), (-(2**40), -(2**31)),
                                          (np.uint64(2**63), 2**31 - 1), (True, 1), (7, 7)])
def test_monte_carlo_result_codes_never_wrap_to_success(code, expect):
    est = lambda design, y1, y2, y3: types.SimpleNamespace(model=MN, result=code)  # noqa: E731
    s = hbjax.monte_carlo(M, D, estimator=est, **MC)
    np.testing.assert_array_equal(s.codes, expect)
    np.testing.assert_array_equal(s.n_valid, [0])


@pytest.mark.parametrize("code", [0.7, jnp.float32(0.0), 1 + 0j])
def test_monte_carlo_refuses_non_integer_result_codes(code):
    est = lambda design, y1, y2, y3: types.SimpleNamespace(model=MN, result=code)  # noqa: E731
    with pytest.raises(TypeError, match=r"`estimator`'s `.result` must be an integer"):
        hbjax.monte_carlo(M, D, estimator=est, **MC)


_LAYOUT_SCRIPT = textwrap.dedent("""
    import hashlib, json, jax
    jax.config.update("jax_enable_x64", True)
    import hbjax
    out = {"devices": len(jax.devices())}
    for r in (96, 130):
        s = hbjax.monte_carlo(hbjax.default_system(), hbjax.default_design(), noise_std=0.1,
                              lengths=[1200], realisations=r, key=jax.random.key(5),
                              progress=False, keep_estimates=True)
        out[r] = [hashlib.sha256(s.estimates[0, :96].tobytes()).hexdigest(),
                  hashlib.sha256(s.estimates.tobytes()).hexdigest(), int(s.n_valid[0])]
    print()
    print(json.dumps(out))
""")


def _layout_run(devices):
    env = dict(os.environ, JAX_PLATFORMS="cpu",
               XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices}")
    out = subprocess.run([sys.executable, "-c", _LAYOUT_SCRIPT], env=env, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_monte_carlo_same_bits_for_any_device_count_and_study_size():
    # N = 1200: a record length at which XLA's reductions round differently for different
    # vmap batch sizes, so a batch that followed R or the device count changed the bits.
    runs = [_layout_run(n) for n in (1, 3, 4)]
    assert [r["devices"] for r in runs] == [1, 3, 4]
    for r in runs:
        assert r["96"][0] == r["130"][0]  # the first 96 realisations of a 130-study
        assert r["96"][2] == 96 and r["130"][2] == 130
    for r in runs:
        r.pop("devices")
    assert runs[0] == runs[1] == runs[2]


# ----------------------------------------------------------------------------- complex input

V = D.staircase_input(60)
_T = 400
_RECORDS = [np.asarray(hbjax.simulate(M, v)) for v in
            (D.constant_input(_T), D.binary_input(_T), D.staircase_input(_T))]


@pytest.mark.parametrize("name, fn, arg, match", [
    ("simulate", lambda v: hbjax.simulate(M, v), V + 1j, "`v` must be real"),
    ("simulate noise", lambda x: hbjax.simulate(M, V, x), np.zeros(60) + 0j, "`noise` must be real"),
    ("play", lambda v: hbjax.play(M.backlash, v), V + 1j, "`v` must be real"),
    ("predict", lambda y: hbjax.predict(M, V, y), V * (1 + 0j), "`y` must be real"),
    ("Backlash", lambda c: hbjax.Backlash(c, c).c1, np.asarray(M.backlash.c1) + 0j,
     "`c1` must be real"),
    ("identify_giri", lambda y1: hbjax.identify_giri(D, y1, *_RECORDS[1:], throw=False).result,
     _RECORDS[0] + 0j, "`y1` must be real"),
])
@pytest.mark.parametrize("transform", ["jit", "vmap"])
def test_complex_input_is_refused_when_traced(name, fn, arg, match, transform):
    arg = jnp.asarray(arg)
    f = jax.jit(fn) if transform == "jit" else jax.vmap(fn)
    with pytest.raises(TypeError, match=match):
        f(arg if transform == "jit" else arg[None])


# ----------------------------------------------------------------------------- overflow

OVERFLOWING = hbjax.Backlash([-1.0, 1.0, 0.01], [1.0, 1.0, 0.01])  # both branches -> +inf
UNSTABLE = hbjax.Hammerstein(M.backlash, hbjax.ARX([-1.5, 0.2], [1.0, 0.5]))
HUGE = np.array([0.0, 1e200, 3.0])


@pytest.mark.parametrize("name, fn, arg, match", [
    ("play", lambda v: hbjax.play(OVERFLOWING, v), HUGE, "play operator's output overflows"),
    ("predict", lambda v: hbjax.predict(hbjax.Hammerstein(OVERFLOWING, M.arx), v, np.zeros(3)),
     HUGE, "one-step prediction overflows"),
    ("predict y", lambda y: hbjax.predict(M, np.zeros(3), y), np.array([0.0, 1.5e308, 0.0]),
     "one-step prediction overflows"),
    ("simulate", lambda v: hbjax.simulate(UNSTABLE, v), np.full(3000, D.h_m),
     "simulated output overflows"),
])
@pytest.mark.parametrize("transform", ["eager", "jit"])
def test_overflow_is_refused_not_returned(name, fn, arg, match, transform):
    f = fn if transform == "eager" else jax.jit(fn)
    with pytest.raises(Exception, match=match) as info:
        jax.block_until_ready(f(arg))
    if transform == "eager":
        assert info.type is ValueError and "Traceback" not in str(info.value)
    # The same calls on finite data still run.
    assert np.all(np.isfinite(f(np.asarray(arg) * 1e-250)))


# ----------------------------------------------------------------------------- scale

_TR = 300
_VR = 1.5 * D.h_m * np.sin(np.arange(_TR) / 7.0)
_YR = np.asarray(hbjax.simulate(M, _VR, 0.1 * np.random.default_rng(3).standard_normal(_TR)))


def test_crlb_is_scale_free_in_noise_std_and_refuses_beyond_float_range():
    unit = hbjax.crlb(MN, (_VR, _YR), noise_std=1.0, h_m=D.h_m).covariance
    tiny = hbjax.crlb(MN, (_VR, _YR), noise_std=1e-100, h_m=D.h_m).covariance
    np.testing.assert_allclose(np.asarray(tiny) / 1e-200, unit, rtol=1e-9, atol=1e-300)
    for sigma in (1e-160, 1e200):
        with pytest.raises(ValueError, match=re.escape("`noise_std` must lie in [1e-150, 1e150]")):
            hbjax.crlb(MN, (_VR, _YR), noise_std=sigma, h_m=D.h_m)


def test_diagnose_sees_a_mismatch_in_data_of_huge_scale():
    # The model explains y, not 1e80 y: the residual correlations must not overflow to 0.
    v = D.h_m * np.sin(np.arange(600) / 20.0)
    y = np.asarray(hbjax.simulate(M, v, 0.1 * np.random.default_rng(4).standard_normal(600)))
    assert hbjax.diagnose(M, v, 1e80 * y, effects=["extra_delay"]).mismatch


@pytest.mark.parametrize("name, call", [
    ("diagnose", lambda s: hbjax.diagnose(M, _VR, s * _YR, effects=["extra_delay"])),
    ("fit", lambda s: hbjax.fit((_VR, s * _YR), na=2, nb=2, m=3, key=jax.random.PRNGKey(0))),
    ("refine", lambda s: hbjax.refine(MN, (_VR, s * _YR), h_m=D.h_m)),
    ("identify_giri", lambda s: hbjax.identify_giri(D, _RECORDS[0], _RECORDS[1] * s, _RECORDS[2])),
])
def test_records_beyond_float_range_of_squares_are_refused_by_name(name, call):
    # Sums of squares of 1e200 overflow float64: a clear refusal naming the record, not a
    # raw LinAlgError or a failure blamed on an assumption of the method.
    with pytest.raises(ValueError, match=r"reaches a magnitude of [\d.]+e\+20\d.*rescale"):
        call(1e200)
