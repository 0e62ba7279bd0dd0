"""An actuator limit the held-out part cannot confirm (tests/generators records): every
burst that drives the internal signal into the limit lies in the fitting part, or the
limit is too small for the held-out 30 % alone, so only a cross-validation over folds of
the whole record can confirm it (hbjax._diagnose.input_clip_nominal); the same records
without the limit must stay clean."""

import numpy as np
from generators.concealed_effects import (_output_noise_gain, arx, hammerstein, make_input,
                                          play, random_base, spread)

import hbjax


def _record(seed, clipped):
    """A filtered-noise input with three short swings in the first 40% of the record; the
    internal signal is clipped just above what it reaches outside the bursts."""
    rng = np.random.default_rng(seed)
    base = random_base(rng, na=2, nb=2, m=3)  # the structure the suite compiles anyway
    n = 2500
    v, _ = make_input(rng, "noise", n, base["amp"])
    for centre in (0.1 * n, 0.22 * n, 0.34 * n):  # one swing up and down each
        window = slice(int(centre) - 75, int(centre) + 75)
        swing = np.sin(2 * np.pi * np.arange(150) / 150) * np.hanning(150)
        v[window] = v[window] + base["amp"] * swing / np.max(swing)
    u = play(v, base["c1"], base["c2"])
    quiet = np.ones(n, bool)
    quiet[:int(0.34 * n) + 80] = False
    upper, lower = float(np.max(u[quiet])), float(np.min(u[quiet]))
    margin = 0.05 * (upper - lower)
    u_drive = np.clip(u, lower - margin, upper + margin) if clipped else u
    y0 = arx(u_drive, np.zeros(n), base["a"], base["b"])
    xi = rng.normal(scale=0.01 * spread(y0), size=n)
    y = arx(u_drive, xi, base["a"], base["b"])
    return hammerstein(base), v, y, u, (lower - margin, upper + margin)


def test_actuator_limit_outside_the_held_out_part_is_found_by_folds():
    """Three random systems of one structure (8 of 10 named on seeds 3-12 of random
    structures when the test was written; the misses were a clip whose fitting-segment BIC
    gain stayed under the margin and one the folds did not confirm); none of the unclipped
    twins gets a finding."""
    named, clean_findings = 0, []
    for seed in (3, 4, 5):
        model, v, y, u, (lower, upper) = _record(seed, clipped=True)
        d = hbjax.diagnose(model, v, y, progress=False)
        clipped = (u < lower) | (u > upper)
        assert not clipped[d.n_fit:].any() and clipped[:d.n_fit].sum() >= 10, "premise"
        if d.best is not None and d.best.effect == "input_saturation":
            assert "folds" in d.best.evidence["validation"]["by"]
            assert d.best.fit_after > d.best.fit_before
            named += 1
        twin = hbjax.diagnose(*_record(seed, clipped=False)[:3], progress=False)
        clean_findings += [f.effect for f in twin.findings]
    assert named >= 2, named
    assert clean_findings == [], clean_findings


#: RMS change of the noise-free output by the small actuator limit, in output-noise
#: standard deviations
RATIO = 0.8


def _small_limit_record(seed, clipped):
    """A record whose actuator limit, on both sides, changes the noise-free output by
    ``RATIO`` output-noise standard deviations (RMS) over the whole record: the held-out part reaches
    it, but a limit that acts on a few percent of the samples is too small for the
    held-out part alone."""
    rng = np.random.default_rng(seed)
    base = random_base(rng, na=2, nb=2, m=3)
    n = 2500
    v, _ = make_input(rng, ("noise", "plateaus")[seed % 2], n, base["amp"])
    u = play(v, base["c1"], base["c2"])
    y_free = arx(u, np.zeros(n), base["a"], base["b"])
    sigma_y = 0.02 * spread(y_free)

    def limited(q):
        return np.clip(u, *np.quantile(u, [q, 1 - q]))

    lo, hi = 1e-3, 0.3  # the clipped fraction per side, by bisection on the RMS change
    for _ in range(30):
        q = np.sqrt(lo * hi)
        change = np.sqrt(np.mean((arx(limited(q), np.zeros(n), base["a"], base["b"])
                                  - y_free) ** 2))
        lo, hi = (q, hi) if change < RATIO * sigma_y else (lo, q)
    u_drive = limited(q) if clipped else u
    xi = rng.normal(scale=sigma_y / _output_noise_gain(base["a"]), size=n)
    return hammerstein(base), v, arx(u_drive, xi, base["a"], base["b"]), u_drive != u


def test_small_actuator_limit_is_confirmed_by_folds():
    """Limits of one noise standard deviation reached by the held-out part too. Before the
    folds were tried wherever no mechanism was found, coloured noise or nothing was named
    on such records (the anchored clip's held-out free run better at z 1.2-1.8 only, its
    fitting-segment BIC gain 1000-4700). Four random systems; the unclipped twins stay
    clean."""
    named, clean_findings = [], []
    for seed in (21, 22, 23, 26):
        model, v, y, acts = _small_limit_record(seed, clipped=True)
        d = hbjax.diagnose(model, v, y, progress=False)
        assert acts[d.n_fit:].sum() >= 10, "premise: the held-out part reaches the limit"
        named.append(d.best.effect if d.best is not None else None)
        twin = hbjax.diagnose(*_small_limit_record(seed, clipped=False)[:3], progress=False)
        clean_findings += [f.effect for f in twin.findings]
    assert named.count("input_saturation") >= 3, named
    assert clean_findings == [], clean_findings
