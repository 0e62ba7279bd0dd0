"""`refine`'s result names the branches as `fit` does: ``P1`` the branch a rising input
drives the output onto. On the core operator (``L = min``, ``H = max``) the labels are
interchangeable, so a solve may end on the same model with ``c1`` and ``c2`` exchanged;
the result, its covariance and flags must come back under the canonical names. Random
paper-class systems from the independent generator, refined from the truth and from the
truth with its labels exchanged."""

import numpy as np
import pytest

import hbjax
from generators.paper_class import INPUT_KINDS, random_input, random_paper_system, simulate_numpy


def _case(seed):
    rng = np.random.default_rng(100 + seed)
    s = random_paper_system(rng, n=int(rng.integers(1, 3)), m=3)
    recs = []
    for k in range(2):
        v = random_input(rng, INPUT_KINDS[(seed + k) % len(INPUT_KINDS)], 800, 1.5 * s["h_m"])
        y0 = simulate_numpy(s, v)[0]
        recs.append((v, simulate_numpy(s, v, 0.02 * np.ptp(y0) * rng.standard_normal(800))[0]))
    return s, recs


@pytest.mark.parametrize("seed", range(4))
def test_refine_names_the_branches_canonically_from_either_labelling(seed):
    s, recs = _case(seed)
    arx = hbjax.ARX(s["a"], s["b"])
    truth = hbjax.Hammerstein(hbjax.Backlash(s["c1"], s["c2"]), arx)
    exchanged = hbjax.Hammerstein(hbjax.Backlash(s["c2"], s["c1"]), arx)
    named = hbjax.normalise_static_gain(truth).backlash  # the truth in the result's gauge
    results = [hbjax.refine(start, recs, throw=False, restarts=0) for start in (truth, exchanged)]
    for res in results:
        c1 = np.asarray(res.model.backlash.c1)
        # P1 estimates the truth's P1, not its P2
        assert np.linalg.norm(c1 - named.c1) < np.linalg.norm(c1 - named.c2)
    same, other = results
    # one model under one naming: the same estimates, standard errors and flags
    np.testing.assert_allclose(float(other.stats["cost"]), float(same.stats["cost"]), rtol=1e-6)
    np.testing.assert_allclose(hbjax.flatten_params(other.model),
                               hbjax.flatten_params(same.model), rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(other.std, same.std, rtol=1e-2, atol=1e-8)
    np.testing.assert_array_equal(np.asarray(other.identified), np.asarray(same.identified))
    np.testing.assert_allclose(np.asarray(other.active_ranges), np.asarray(same.active_ranges),
                               rtol=1e-9)
