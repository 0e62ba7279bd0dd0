"""``refine``'s restarts: a refinement that fails (a far start's poor optimum the quality
checks refuse) is taken up by a multi-start fit of the same records by default, and with
``restarts=k`` also one whose errors fail the residual tests; on a refinement without that
problem nothing changes, and ``restarts=0`` refines from the start alone."""

import importlib
from unittest import mock

import numpy as np
import pytest
from scipy.stats import chi2

import hbjax
from tests.generators.paper_class import to_hbjax
from tests.generators.paper_runs import reproduce

_refine_module = importlib.import_module("hbjax._identify.refine")


def _paper_run(seed, system, level, draw, noise_at="equation", push=True):
    """A run of the paper-mode study: ``(records, h_m, closed-form start, its refinement
    with restarts=0, the refinement from the true system, the allowance)``; the allowance
    is ``sigma^2 chi2_p(0.99)`` in the mean squared residual. ``push=False``: the
    refinement with restarts=0 also leaves out the push-through escape, so that a test
    sees what the restarts do on their own."""
    sys_, design, records, sigma = reproduce(system, level, draw, seed=seed,
                                             levels=[0.01, 0.03, 0.05], draws=14, T=3000,
                                             noise_at=noise_at)
    h_m = sys_["h_m"]
    start = hbjax.identify_giri(design, *(y for _, y in records)).model
    with mock.patch.object(_refine_module, "escape_pushed_through",
                           _refine_module.escape_pushed_through if push else lambda res, *_: res):
        plain = hbjax.refine(start, records, h_m=h_m, restarts=0, throw=False)
    truth = hbjax.refine(hbjax.normalise(to_hbjax(sys_), h_m), records, h_m=h_m)
    p = sys_["na"] + sys_["nb"] + 2 * sys_["m"] - 1
    allowance = sigma**2 * chi2.ppf(0.99, p) / float(truth.stats["samples"])
    return records, h_m, start, plain, truth, allowance


def test_restarts_leave_the_local_minima_of_a_far_start():
    """``refine`` on paper-mode runs (the independent generator, the studies of
    ``benchmarks/identify_random.py``) whose closed-form start is so far off that the
    refinement from it alone (``restarts=0``) ends in a poor optimum refused as
    ``branches_cross`` or ``no_input_effect`` (seed 5, 352 682 and 25 437 sigma^2 above the
    truth; under the suite's compiler flags the first ends in a local minimum reported as
    success, 28 times the allowance above, whose errors fail the residual tests): by
    default (16 random starts where the result fails or its errors fail those tests) it
    reaches the cost of the refinement started from the true system. On a run without
    that problem the default changes nothing.
    (The seed-3 local minima this test used before stopped on a kink of the cost, which
    plain refinement now leaves: ``tests/test_giri_band.py``.)"""
    far = [(5, 4, 0.03, 7), (5, 43, 0.03, 11)]
    exercised = 0
    for seed, system, level, draw in far + [(3, 16, 0.01, 0)]:
        records, h_m, start, plain, truth, allowance = _paper_run(seed, system, level, draw,
                                                                  push=False)
        above = float(plain.stats["cost"]) - float(truth.stats["cost"])
        default = hbjax.refine(start, records, h_m=h_m)  # throw=True
        assert float(default.stats["cost"]) - float(truth.stats["cost"]) <= allowance
        if (seed, system, level, draw) in far:
            exercised += plain.result != hbjax.RESULTS.successful or above > allowance
        else:
            assert plain.result == hbjax.RESULTS.successful and above <= allowance
            np.testing.assert_array_equal(hbjax.flatten_params(default.model),
                                          hbjax.flatten_params(plain.model))
    assert exercised == 2, exercised  # the plain refinement falls short on both far starts
    with pytest.raises(ValueError, match="restarts"):
        hbjax.refine(start, records, h_m=h_m, restarts=-1)


def test_restarts_where_the_first_samples_show_the_initial_state_misplaced():
    """A paper-mode run with the noise at the output (seed 3, system 20, 1 %, draw 3 of
    ``identify_random.py --noise-at output``): the refinement from the closed form alone
    ends where the play operator holds its initial state at the constant-input record's
    first samples while the records show it moved, a local minimum about 55 sigma^2 above
    the optimum whose whiteness and independence tests pass. Its first samples' errors
    (``refine``'s start-up test) call for the restarts, which reach the optimum."""
    from hbjax._identify.refine import startup_suspect

    records, h_m, start, plain, truth, allowance = _paper_run(3, 20, 0.01, 3, noise_at="output",
                                                              push=False)
    assert plain.result == hbjax.RESULTS.successful
    assert float(plain.stats["cost"]) - float(truth.stats["cost"]) > allowance
    assert startup_suspect(plain, records)
    assert not startup_suspect(truth, records)
    default = hbjax.refine(start, records, h_m=h_m)
    assert float(default.stats["cost"]) - float(truth.stats["cost"]) <= allowance


def test_push_through_leaves_a_flat_extrapolation():
    """Paper-mode runs with the noise at the output whose refinement, without the
    push-through escape (``refine_kinks.pushed_through``), stops in a local minimum reported
    as success: seed 7, system 14, 5 %, draw 6 (73.6 sigma^2 above the true system's cost,
    every residual and start-up test passed: no restart is called for), and seed 3,
    system 20, 1 %, draw 3 (the start-up test's case above). Refining again from each
    branch pushed through the other at the median of the inputs where it is an
    extrapolation reaches the cost of the refinement from the true system, restarts off."""
    from hbjax._identify.refine import residuals_suspect, startup_suspect

    for seed, system, level, draw in [(7, 14, 0.05, 6), (3, 20, 0.01, 3)]:
        records, h_m, start, held, truth, allowance = _paper_run(
            seed, system, level, draw, noise_at="output", push=False)
        assert held.result == hbjax.RESULTS.successful
        assert float(held.stats["cost"]) - float(truth.stats["cost"]) > allowance
        if seed == 7:  # nothing else would have looked further
            assert not residuals_suspect(held, records, "prediction")
            assert not startup_suspect(held, records)
        pushed = hbjax.refine(start, records, h_m=h_m, restarts=0)  # throw=True
        assert float(pushed.stats["cost"]) - float(truth.stats["cost"]) <= allowance
