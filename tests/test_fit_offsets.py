"""Records with an operating point: `fit` on an output shifted far from zero, and on an
input held far from zero, reaches what it reaches on the same records without the shift
(``hbjax/_identify/centring.py``).
Systems and inputs come from the independent generator (``tests/generators/paper_class.py``);
the shifts are drawn here."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hbjax
from hbjax._identify.centring import record_centres, recentring_matrix
from tests.generators.paper_class import random_input, random_paper_system, simulate_numpy


def _fit(v, y, sys_, key):
    return hbjax.fit((v, y), na=len(sys_["a"]), nb=len(sys_["b"]), m=len(sys_["c1"]),
                     key=jax.random.PRNGKey(key), starts=8, throw=False, progress=False)


def _branch_std(res, x):
    """Standard deviations of ``P1(x)`` and ``P2(x)`` from the result's covariance: values
    of the model, the same in any coordinates of its coefficients."""
    m = res.model.backlash.m
    cov = np.asarray(res.covariance)[-2 * m:, -2 * m:]
    powers = np.asarray(x, float)[:, None] ** np.arange(m)
    out = []
    for k in range(2):
        block = cov[k * m:(k + 1) * m, k * m:(k + 1) * m]
        out.append(np.sqrt(np.einsum("gi,ij,gj->g", powers, block, powers)))
    return np.concatenate(out)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_shifted_records_fit_as_the_unshifted_ones(seed):
    """Output moved by 20-10^4 times its range, input moved by 5-20 half-ranges, m = 4-5:
    before, the shifted output sent 31 of 32 starts to a slow-pole model (free-run fit
    28 % against 99.8 %), and the shifted input read every branch coefficient as
    unidentified (``branches_undetermined``) on models that validate at 99.97 %."""
    rng = np.random.default_rng(300 + seed)
    sys_ = random_paper_system(rng, m=int(rng.integers(4, 6)))
    scale = 2.0 * sys_["h_m"]
    v = random_input(rng, "multisine", 1500, scale)
    free, _ = simulate_numpy(sys_, v)
    y, _ = simulate_numpy(sys_, v, 0.005 * float(np.ptp(free)) * rng.normal(size=v.size))
    y_shift = rng.choice([-1, 1]) * 10 ** rng.uniform(1.3, 4) * float(np.ptp(free))
    v_shift = rng.choice([-1, 1]) * rng.uniform(5, 20) * scale

    plain = _fit(v, y, sys_, seed)
    output_moved = _fit(v, y + y_shift, sys_, seed)
    input_moved = _fit(v + v_shift, y, sys_, seed)
    for res in (plain, output_moved, input_moved):
        assert res.result == hbjax.RESULTS.successful, res.message
        assert not res.unidentified, res.unidentified
    # the same optimum (up to where each solve stops: 1.8e-4 apart measured; the output
    # moved by 10^3 ranges stopped at 1.15 times the cost before the centring)
    cost = float(plain.stats["cost"])
    assert abs(float(output_moved.stats["cost"]) / cost - 1) < 1e-3
    assert abs(float(input_moved.stats["cost"]) / cost - 1) < 1e-3
    # the same model, reported in the records' own coordinates: from the same internal
    # state (the start estimated on each), the same free run up to the offset
    v_val = random_input(rng, "multisine", 800, scale)
    y_val, _ = simulate_numpy(sys_, v_val)
    runs = [hbjax.compare(plain.model, v_val, y_val).y_hat,
            hbjax.compare(output_moved.model, v_val, y_val + y_shift).y_hat - y_shift,
            hbjax.compare(input_moved.model, v_val + v_shift, y_val).y_hat]
    for run in runs[1:]:
        assert np.max(np.abs(np.asarray(run) - np.asarray(runs[0]))) < 1e-3 * np.ptp(y_val)
    np.testing.assert_allclose(np.asarray(input_moved.data_range) - v_shift,
                               np.asarray(plain.data_range), rtol=1e-9, atol=1e-9 * scale)
    # and its covariance carried over: the branch values' uncertainty is the same
    x = np.linspace(v.min(), v.max(), 7)
    np.testing.assert_allclose(_branch_std(input_moved, x + v_shift), _branch_std(plain, x),
                               rtol=0.02)


def test_the_centre_is_taken_out_only_far_from_zero():
    def centres(v, y, initial_state="estimate"):
        return tuple(float(c) for c in record_centres([(v, y)], initial_state))

    ramp = jnp.linspace(-1.0, 3.0, 9)
    assert centres(ramp, ramp) == (0.0, 0.0)
    # the input's midpoint; the output's first sample, where the criterion's play starts
    assert centres(ramp + 11.0, ramp + 101.0) == (12.0, 100.0)
    assert centres(ramp + 11.0, ramp + 101.0, "zero") == (12.0, 0.0)  # from rest: as recorded
    assert centres(jnp.full(9, 5.0), ramp) == (0.0, 0.0)  # a constant input
    t = recentring_matrix(jnp.asarray(2.0), 4)
    d = np.array([0.5, -1.0, 0.25, 0.125])
    x = np.linspace(-3.0, 5.0, 11)
    np.testing.assert_allclose(np.polynomial.polynomial.polyval(x, np.asarray(t) @ d),
                               np.polynomial.polynomial.polyval(x - 2.0, d), rtol=1e-12)


def _moved_branch(c, shift):
    """Coefficients of ``P(v - shift)`` in powers of ``v`` (the branch of a record whose
    input is moved by ``shift``)."""
    out = np.zeros(len(c))
    for j, cj in enumerate(np.asarray(c, float)):
        term = np.polynomial.polynomial.polypow([-shift, 1.0], j)
        out[:term.size] += cj * term
    return out


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_refine_solves_records_far_from_zero_as_fit_does(seed):
    """`refine` from the true system, on a short record whose output lies 30-100 ranges
    from zero (and input 5-15 half-ranges), ends where `fit` ends (scored alike: the
    one-step errors from the initial state `compare` estimates). Before `refine` centred
    such records its criterion started the play operator beyond both branches: on one
    record of ``benchmarks/fit_offsets.py --seed 2`` it ended 3393 ``sigma^2`` above
    `fit`'s model and reported a success."""
    rng = np.random.default_rng(500 + seed)
    sys_ = random_paper_system(rng, m=2)
    scale = 2.0 * sys_["h_m"]
    v = random_input(rng, "filtered_noise", 300, scale)
    free, _ = simulate_numpy(sys_, v)
    sigma = 0.002 * float(np.ptp(free))
    y, _ = simulate_numpy(sys_, v, sigma * rng.normal(size=v.size))
    y_shift = rng.choice([-1, 1]) * rng.uniform(30, 100) * float(np.ptp(free))
    v_shift = rng.choice([-1, 1]) * rng.uniform(5, 15) * scale
    V, Y = v + v_shift, y + y_shift
    a, b = np.asarray(sys_["a"], float), np.asarray(sys_["b"], float)
    delta = (1.0 + a.sum()) * y_shift / b.sum()  # the output's offset, carried by the branches
    truth = hbjax.Hammerstein(
        hbjax.Backlash(*(_moved_branch(c, v_shift) + delta for c in (sys_["c1"], sys_["c2"]))),
        hbjax.ARX(a, b))
    refined = hbjax.refine(hbjax.normalise_static_gain(truth), [(V, Y)],
                           initial_state="estimate", throw=False)
    fitted = hbjax.fit((V, Y), na=len(a), nb=len(b), m=2, key=jax.random.PRNGKey(seed),
                       starts=8, throw=False, progress=False)
    assert refined.result == hbjax.RESULTS.successful, refined.message
    assert fitted.result == hbjax.RESULTS.successful, fitted.message

    def squares(model):  # in noise variances
        return V.size * float(hbjax.compare(model, V, Y, horizon=1).rmse) ** 2 / sigma**2

    assert abs(squares(refined.model) - squares(fitted.model)) < 1.0
    # reported in the records' own coordinates: its input range is the recorded one
    np.testing.assert_allclose(np.asarray(refined.data_range), [V.min(), V.max()], rtol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [502, 503])
def test_records_from_rest_off_their_midpoint_fit_as_the_unmoved_ones(seed):
    """Two short records from rest, moved by 40 output ranges, whose start lies away from
    the outputs' midpoint: `fit` and `refine` (from the true system) reach the unmoved
    records' optimum. With the output centred at its midpoint the criterion's play
    operator started 14 % of the range away from the records' start, and on the first
    seed both ended 7598 ``sigma^2`` above the true system's 517, reported as successes."""
    rng = np.random.default_rng(seed)
    sys_ = random_paper_system(rng, m=2)
    scale = 2.0 * sys_["h_m"]
    inputs = [random_input(rng, "filtered_noise", n, scale) for n in (300, 220)]
    free = [simulate_numpy(sys_, v)[0] for v in inputs]
    sigma = 0.002 * float(np.ptp(free[0]))
    outputs = [simulate_numpy(sys_, v, sigma * rng.normal(size=v.size))[0] for v in inputs]
    y_shift = 40.0 * float(np.ptp(free[0]))
    unmoved = list(zip(inputs, outputs))
    moved = [(v, y + y_shift) for v, y in unmoved]
    orders = dict(na=len(sys_["a"]), nb=len(sys_["b"]), m=2)

    def squares(model, records):  # one-step errors from compare's initial state, in sigma^2
        return sum(v.size * float(hbjax.compare(model, v, y, horizon=1).rmse) ** 2
                   for v, y in records) / sigma**2

    def fitted(records):
        return hbjax.fit(records, key=jax.random.PRNGKey(0), starts=8, throw=False,
                         progress=False, **orders)

    a, b = np.asarray(sys_["a"], float), np.asarray(sys_["b"], float)
    delta = (1.0 + a.sum()) * y_shift / b.sum()  # the offset, carried by the branches
    truth = hbjax.Hammerstein(hbjax.Backlash(np.asarray(sys_["c1"]) + np.eye(2)[0] * delta,
                                             np.asarray(sys_["c2"]) + np.eye(2)[0] * delta),
                              hbjax.ARX(a, b))
    refined = hbjax.refine(hbjax.normalise_static_gain(truth), moved,
                           initial_state="estimate", throw=False)
    reference = squares(fitted(unmoved).model, unmoved)
    for res in (fitted(moved), refined):
        assert res.result == hbjax.RESULTS.successful, res.message
        assert abs(squares(res.model, moved) - reference) < 1.0
