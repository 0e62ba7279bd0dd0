"""Property-based tests of the simulator (hypothesis, derandomized for CI).

The play operator (paper Fig. 2, ``docs/conventions.md``): its output stays in the band
``[L(v), H(v)]``, holds still under a constant input, and is rate independent. The ARX block
(eq. (10)) is linear in ``(u, xi)`` and time invariant. ``simulate`` agrees with the
independent NumPy loop ``reference_simulate``.

Lengths and orders are drawn from small sets so that the jitted simulator compiles a bounded
number of shapes.
"""

import numpy as np
import pytest
from conftest import reference_simulate
from hypothesis import given, settings
from hypothesis import strategies as st

import hbjax

CI = settings(max_examples=40, deadline=None, derandomize=True, database=None)

LENGTHS = st.sampled_from([1, 5, 24])
finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False, width=64)
small = st.floats(-0.45, 0.45, allow_nan=False, allow_infinity=False, width=64)


def vectors(length, elements=finite):
    return st.lists(elements, min_size=length, max_size=length).map(np.array)


@st.composite
def backlashes(draw):
    m = draw(st.sampled_from([1, 2, 3]))
    c1 = draw(vectors(m, st.floats(-2.0, 2.0, allow_nan=False, width=64)))
    c2 = draw(vectors(m, st.floats(-2.0, 2.0, allow_nan=False, width=64)))
    return hbjax.Backlash(c1, c2)


@st.composite
def models(draw):
    na = draw(st.sampled_from([0, 1, 2]))
    nb = draw(st.sampled_from([1, 2]))
    # |a_i| <= 0.45 with na <= 2: |A| has no root outside radius 0.9, records stay finite.
    a, b = draw(vectors(na, small)), draw(vectors(nb, finite))
    return hbjax.Hammerstein(draw(backlashes()), hbjax.ARX(a, b))


@st.composite
def records(draw):
    T = draw(LENGTHS)
    return draw(vectors(T)), draw(vectors(T)), draw(finite)


@CI
@given(backlash=backlashes(), rec=records())
def test_play_output_lies_in_the_band(backlash, rec):
    v, _, u0 = rec
    u = np.asarray(hbjax.play(backlash, v, u0=u0))
    low, high = (np.asarray(x) for x in backlash.band(v))
    tol = 1e-12 * (1.0 + np.abs(low) + np.abs(high))
    assert u.shape == v.shape
    assert np.all(low - tol <= u) and np.all(u <= high + tol)


@CI
@given(backlash=backlashes(), v0=finite, level=finite, u0=finite, T=LENGTHS)
def test_constant_input_after_the_first_sample_leaves_u_constant(backlash, v0, level, u0, T):
    v = np.full(T + 1, level)
    v[0] = v0
    u = np.asarray(hbjax.play(backlash, v, u0=u0))
    np.testing.assert_array_equal(u[1:], u[1])


@CI
@given(backlash=backlashes(), rec=records(), data=st.data())
def test_play_is_rate_independent(backlash, rec, data):
    # Holding each input sample for k_t >= 1 samples holds each output sample as long.
    v, _, u0 = rec
    repeats = np.array(data.draw(st.lists(st.integers(1, 3), min_size=v.size, max_size=v.size)))
    u = np.asarray(hbjax.play(backlash, v, u0=u0))
    u_slow = np.asarray(hbjax.play(backlash, np.repeat(v, repeats), u0=u0))
    np.testing.assert_array_equal(u_slow, np.repeat(u, repeats))


def _linear_part(model):
    """The ARX block alone: the identity play operator (P1 = P2 = v) passes u = v through."""
    return hbjax.Hammerstein(hbjax.Backlash([0.0, 1.0], [0.0, 1.0]), model.arx)


@CI
@given(model=models(), r1=records(), r2=records(), alpha=finite, beta=finite)
def test_arx_block_is_linear_in_u_and_xi(model, r1, r2, alpha, beta):
    (u1, xi1, _), (u2, xi2, _) = r1, r2
    T = min(u1.size, u2.size)
    u1, xi1, u2, xi2 = u1[:T], xi1[:T], u2[:T], xi2[:T]
    arx = _linear_part(model)
    y = np.asarray(hbjax.simulate(arx, alpha * u1 + beta * u2, alpha * xi1 + beta * xi2))
    y1, y2 = np.asarray(hbjax.simulate(arx, u1, xi1)), np.asarray(hbjax.simulate(arx, u2, xi2))
    scale = 1.0 + np.max(np.abs(alpha * y1)) + np.max(np.abs(beta * y2))
    np.testing.assert_allclose(y, alpha * y1 + beta * y2, rtol=0, atol=1e-11 * scale)


@CI
@given(model=models(), rec=records(), delay=st.sampled_from([1, 3]))
def test_arx_block_is_time_invariant(model, rec, delay):
    # Zero initial conditions: delaying (u, xi) by d samples delays y by d samples.
    u, xi, _ = rec
    arx = _linear_part(model)
    y = np.asarray(hbjax.simulate(arx, u, xi))
    pad = np.zeros(delay)
    y_late = np.asarray(hbjax.simulate(arx, np.r_[pad, u], np.r_[pad, xi]))
    np.testing.assert_array_equal(y_late[:delay], 0.0)
    np.testing.assert_array_equal(y_late[delay:], y)


@CI
@given(model=models(), rec=records())
def test_simulate_equals_the_numpy_loop(model, rec):
    v, xi, u0 = rec
    y = np.asarray(hbjax.simulate(model, v, xi, u0=u0))
    bl, arx = model.backlash, model.arx
    y_ref, u_ref = reference_simulate(bl.c1, bl.c2, arx.a, arx.b, v, xi, u0)
    scale = 1.0 + np.max(np.abs(y_ref))
    np.testing.assert_allclose(y, y_ref, rtol=0, atol=1e-11 * scale)
    np.testing.assert_allclose(np.asarray(hbjax.play(bl, v, u0=u0)), u_ref, rtol=0,
                               atol=1e-12 * (1.0 + np.max(np.abs(u_ref))))


@CI
@given(model=models(), rec=records())
def test_predict_recovers_the_equation_error(model, rec):
    # Under the true model y - y_hat is exactly the equation error xi (eq. (10)).
    v, xi, u0 = rec
    y = hbjax.simulate(model, v, xi, u0=u0)
    y_hat = np.asarray(hbjax.predict(model, v, y, u0=u0))
    scale = 1.0 + np.max(np.abs(np.asarray(y)))
    np.testing.assert_allclose(np.asarray(y) - y_hat, xi, rtol=0, atol=1e-11 * scale)


def test_properties_would_catch_a_wrong_simulator():
    # The oracle is sharp: a one-sample shift of B (direct feed-through) is detected.
    model = hbjax.default_system()
    v = hbjax.default_design().staircase_input(24)
    bl, arx = model.backlash, model.arx
    y_ref, _ = reference_simulate(bl.c1, bl.c2, arx.a, np.r_[0.0, arx.b], v, np.zeros(24))
    with pytest.raises(AssertionError):
        np.testing.assert_allclose(np.asarray(hbjax.simulate(model, v)), y_ref, atol=1e-9)


@pytest.mark.parametrize("T", [1, 2, 3])
def test_records_shorter_than_the_orders_keep_their_length(T):
    # Found by the properties above: lags longer than the record used to lengthen it.
    model = hbjax.Hammerstein(hbjax.default_system().backlash, hbjax.ARX([0.1, 0.2, 0.3], [1.0, 0.5, 0.2]))
    v, y = np.linspace(1.0, 5.0, T), np.linspace(-1.0, 1.0, T)
    y_hat = np.asarray(hbjax.predict(model, v, y))
    assert y_hat.shape == (T,)
    y_ref, _ = reference_simulate(model.backlash.c1, model.backlash.c2, model.arx.a,
                                  model.arx.b, v, np.zeros(T))
    np.testing.assert_allclose(np.asarray(hbjax.simulate(model, v)), y_ref, atol=1e-12)
