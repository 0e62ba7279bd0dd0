"""A refit in the diagnosis fits a branch only in the directions its fitting segment sees.

The records here are built from the independent generator's random systems
(``tests/generators/concealed_effects.py``): the fitting part's input stays on one side of
the range and the held-out part then sweeps all of it, so a branch's shape over most of
the held-out inputs is an extrapolation from the fitting part. A refit that moved those
directions freely simulated the held-out part far worse than the nominal model on a
record of a plateau input (92 % -> 53 %, benchmarks/RESULTS.md), and no mechanism built on
the refitted base could then be confirmed there.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

import hbjax
from generators.concealed_effects import hammerstein, nominal_output, play, random_base
from hbjax._diagnose import candidates as cands
from hbjax._diagnose.kernel_effect import base_theta

jax.config.update("jax_enable_x64", True)

N, N_FIT = 2000, 1400


def _one_sided_input(rng, amp):
    """Slow sines: on ``[-amp, -0.2 amp]`` for the first ``N_FIT`` samples, then over
    ``[-amp, amp]`` (random periods and phases)."""
    t = np.arange(N)
    p1, p2 = rng.uniform(150, 250), rng.uniform(150, 250)
    first = -0.6 * amp + 0.4 * amp * np.sin(2 * np.pi * t / p1 + rng.uniform(0, 2 * np.pi))
    second = amp * np.sin(2 * np.pi * t / p2 + rng.uniform(0, 2 * np.pi))
    return np.where(t < N_FIT, first, second)


def _case(seed):
    """A random system and a clean record of it (equation noise 2 % of the output's std)."""
    rng = np.random.default_rng(seed)
    base = random_base(rng, na=2, nb=2, m=3)
    v = _one_sided_input(rng, base["amp"])
    sigma = 0.02 * float(np.std(nominal_output(base, v, np.zeros(N))))
    return base, v, nominal_output(base, v, sigma * rng.standard_normal(N))


def test_a_branch_seen_on_one_side_is_fitted_only_in_the_directions_seen():
    # the same random systems and inputs as below; the property is read off the
    # directions with plain NumPy: every fitted direction changes the branch on the active
    # samples by at least SEEN_FRACTION of its mean square over the record's inputs, and
    # every change outside their span by less
    for seed in range(6):
        base, v, _ = _case(seed)
        model = hammerstein(base)
        lay, theta = base_theta(model)
        u = play(v, base["c1"], base["c2"])
        dirs = cands.branch_directions(lay, theta, v[:N_FIT], u[:N_FIT], v)
        assert dirs["c1"] is not None or dirs["c2"] is not None, seed  # one side extrapolates
        all_powers = np.vander(v, 3, increasing=True)
        for name, c in (("c1", base["c1"]), ("c2", base["c2"])):
            on = np.isclose(np.vander(v[:N_FIT], 3, increasing=True) @ c, u[:N_FIT],
                            rtol=0, atol=1e-9 * np.ptp(u))
            seen = np.vander(v[:N_FIT][on], 3, increasing=True)

            def ratio(delta, seen=seen):
                return (np.mean((seen @ delta) ** 2) if len(seen) else 0.0) / np.mean(
                    (all_powers @ delta) ** 2)

            D = np.eye(3) if dirs[name] is None else dirs[name]
            for delta in D.T:
                assert ratio(delta) >= cands.SEEN_FRACTION * (1 - 1e-6), (seed, name)
            # a change outside the fitted span (orthogonal to it in the mean square over
            # the record's inputs) is one the fitting segment barely sees
            gram = all_powers.T @ all_powers
            rng = np.random.default_rng(seed)
            for _ in range(20):
                delta = rng.standard_normal(3)
                if D.shape[1]:
                    delta -= D @ np.linalg.solve(D.T @ gram @ D, D.T @ gram @ delta)
                if np.linalg.norm(delta) < 1e-9:
                    continue
                assert ratio(delta) < cands.SEEN_FRACTION, (seed, name, ratio(delta))


@pytest.mark.slow
def test_refits_do_not_extrapolate_a_branch_into_the_held_out_part():
    # Random systems (na = nb = 2, m = 3), one-sided fitting inputs, clean records: nothing
    # is reported, and the refit simulates the held-out part about as well as the nominal
    # model (the truth here). Measured on these six records: the refit loses 0.02-6.3
    # points of held-out fit (median 1.8); with every branch coefficient free it lost
    # 3.5-73.5 (median 8.9), the refit's branches moving with the noise where the fitting
    # part never put the play on them.
    losses = []
    for seed in range(6):
        base, v, y = _case(seed)
        d = hbjax.diagnose(hammerstein(base), v, y, holdout=1 - N_FIT / N, split="tail")
        assert not d.findings, (seed, [f.effect for f in d.findings])
        losses.append(d.candidates["nominal"]["fit_sim"]
                      - d.candidates["parameter_mismatch"]["fit_sim"])
    assert np.median(losses) < 3.0 and max(losses) < 10.0, losses


def test_an_input_of_two_levels_fits_every_direction_and_runs():
    # a PRBS-like record of two levels and m = 3 or 4: the record's own mean square of the
    # branch powers is singular (in rounding only for some records, where its
    # factorisation raised inside diagnose); the directions cannot be told apart, so every
    # one is fitted, and a clean record stays clean
    for seed, m in ((0, 3), (1, 4), (2, 3), (3, 4)):
        rng = np.random.default_rng(seed)
        base = random_base(rng, na=2, nb=1, m=m)
        v = base["amp"] * np.repeat(rng.choice([-1.0, 1.0], 40), 25)
        sigma = 0.02 * float(np.std(nominal_output(base, v, np.zeros(v.size))))
        y = nominal_output(base, v, sigma * rng.standard_normal(v.size))
        model = hammerstein(base)
        lay, theta = base_theta(model)
        u = play(v, base["c1"], base["c2"])
        assert cands.branch_directions(lay, theta, v[:700], u[:700], v) == {"c1": None,
                                                                             "c2": None}
        d = hbjax.diagnose(model, v, y)
        assert d.verdict == "consistent" and not d.findings, (seed, d)
    # two levels whose mean square of powers passes a rank test in rounding but cannot be
    # factorised: the case that raised
    base = random_base(np.random.default_rng(5), na=2, nb=1, m=3)
    lay, theta = base_theta(hammerstein(base))
    rng = np.random.default_rng(3)
    levels = rng.uniform(-1.5, 1.5, 2) * base["amp"]
    v = np.repeat(rng.choice(levels, 40), 25)
    u = play(v, base["c1"], base["c2"])
    assert cands.branch_directions(lay, theta, v[:700], u[:700], v) == {"c1": None, "c2": None}
