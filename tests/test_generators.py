"""The independent random-system generator keeps its promises, and its plain-NumPy simulator
agrees with ``hbjax.simulate`` sample by sample."""

import numpy as np
import pytest

import hbjax
from tests.generators.paper_class import (
    INPUT_KINDS,
    design_levels,
    paper_violations,
    polyval_asc,
    predict_numpy,
    random_closing_loop_system,
    random_input,
    random_paper_system,
    simulate_numpy,
    to_hbjax,
)


@pytest.fixture(scope="module")
def paper_systems():
    rng = np.random.default_rng(20240611)
    return [random_paper_system(rng) for _ in range(200)]


def test_paper_systems_linear_block(paper_systems):
    for sys in paper_systems:
        a, b = sys["a"], sys["b"]
        assert 1 <= sys["na"] == len(a) <= 4 and len(b) == sys["nb"] == sys["na"] == sys["n"]
        radii = np.abs(np.roots(np.concatenate([[1.0], a])))
        assert np.all((radii >= 0.2 - 1e-9) & (radii <= 0.95 + 1e-9))  # A3
        assert abs(b.sum()) >= 0.2 * np.abs(b).sum()  # A5 with a margin
        assert np.all(b[: sys["delay"]] == 0) and b[sys["delay"]] != 0
    # the draws cover every order, every m, delays and complex poles
    assert {s["na"] for s in paper_systems} == {1, 2, 3, 4}
    assert {s["m"] for s in paper_systems} == {2, 3, 4, 5}
    assert sum(s["delay"] > 0 for s in paper_systems) >= 10
    complex_poles = [np.any(np.abs(np.roots(np.r_[1.0, s["a"]]).imag) > 0) for s in paper_systems]
    assert sum(complex_poles) >= 20


def test_paper_systems_band(paper_systems):
    gaps = []
    for sys in paper_systems:
        h_m, c1, c2 = sys["h_m"], sys["c1"], sys["c2"]
        v = np.linspace(-2 * h_m, 2 * h_m, 10_007)  # a grid different from the generator's
        p1, p2 = polyval_asc(c1, v), polyval_asc(c2, v)
        out_range = max(p1.max(), p2.max()) - min(p1.min(), p2.min())
        assert np.min(p2 - p1) > 0.005 * out_range  # P1 the lower edge, no crossing
        assert polyval_asc(c1, h_m) > polyval_asc(c2, -h_m)  # the swing crosses the gap
        for c in (c1, c2):  # A4: zeros inside (-h_m, h_m)
            assert polyval_asc(c, -h_m) < 0 < polyval_asc(c, h_m)
        gaps.append(np.mean(p2 - p1) / out_range)
        assert paper_violations(sys) == []
    gaps = np.array(gaps)
    assert gaps.min() >= 0.015 and gaps.max() <= 0.5
    assert np.mean(gaps < 0.04) > 0.1 and np.mean(gaps > 0.15) > 0.1  # narrow and wide bands


def test_paper_systems_pass_hbjax_assumption_checks(paper_systems):
    for sys in paper_systems:
        design = hbjax.GiriDesign(n=sys["n"], m=sys["m"], h_m=sys["h_m"])
        design.check_model(to_hbjax(sys), assumptions=True)


def test_staircase_plateaus_sit_on_the_branches(paper_systems):
    """Under the package's own v1, v2, v3 the NumPy play operator's plateau ends are on P1
    (rising levels) and P2 (falling levels)."""
    for sys in paper_systems[:60]:
        n, m, h_m = sys["n"], sys["m"], sys["h_m"]
        design = hbjax.GiriDesign(n=n, m=m, h_m=h_m)
        period = 2 * m * (n + 1)
        v3 = np.asarray(design.staircase_input(3 * period))
        levels = design_levels(h_m, m)
        np.testing.assert_allclose(v3[: period].reshape(2 * m, n + 1)[:, 0], levels, rtol=1e-14)
        _, u = simulate_numpy(sys, v3)
        ends = u[period + n :: n + 1][: 2 * m]  # second period, last sample of each plateau
        want = np.where(levels > 0, polyval_asc(sys["c1"], levels), polyval_asc(sys["c2"], levels))
        np.testing.assert_allclose(ends, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())


def test_violations_are_detected():
    rng = np.random.default_rng(3)
    sys = random_paper_system(rng, n=2, m=3)
    swapped = dict(sys, c1=sys["c2"], c2=sys["c1"])
    assert any("cross" in s for s in paper_violations(swapped))
    unstable = dict(sys, a=np.array([-2.0, 1.1]))
    assert any("A3" in s for s in paper_violations(unstable))
    narrow = dict(sys, h_m=sys["h_m"] / 20)  # zeros leave (-h_m, h_m), the swing stays in the band
    assert any("A4" in s for s in paper_violations(narrow))


def test_closing_loop_systems_meet_inside_the_input_range():
    rng = np.random.default_rng(11)
    kinds = set()
    for _ in range(40):
        sys = random_closing_loop_system(rng)
        kinds.add(sys["kind"])
        scale, v_meet = sys["scale"], sys["v_meet"]
        assert 0.5 * scale - 1e-9 <= abs(v_meet) <= 0.85 * scale + 1e-9
        v = np.linspace(-scale, scale, 20_001)
        gap = polyval_asc(sys["c2"], v) - polyval_asc(sys["c1"], v)
        out = polyval_asc(sys["c2"], v)
        tol = 1e-9 * (out.max() - out.min())
        assert abs(polyval_asc(sys["c2"], v_meet) - polyval_asc(sys["c1"], v_meet)) <= tol
        assert gap.max() > 0.05 * (out.max() - out.min())  # a real band elsewhere
        if sys["kind"] == "cross":
            assert gap.min() < -tol  # the branches swap beyond v_meet
        else:
            assert gap.min() >= -tol
        for c in (sys["c1"], sys["c2"]):
            assert np.all(np.diff(polyval_asc(c, v)) > 0)
    assert kinds == {"touch", "cross"}


def test_random_inputs():
    rng = np.random.default_rng(5)
    for kind in INPUT_KINDS:
        for scale in (0.5, 6.0):
            v = random_input(rng, kind, 3000, scale)
            assert v.shape == (3000,) and np.all(np.isfinite(v))
            assert np.max(np.abs(v)) <= scale * (1 + 1e-12)
            assert np.max(np.abs(v)) >= 0.7 * scale
            assert np.std(v) > 0.1 * scale
    with pytest.raises(ValueError, match="kind"):
        random_input(rng, "nope", 10, 1.0)


def test_simulate_numpy_hand_computed():
    # P1 = v - 1, P2 = v + 1; y(t) = 0.5 y(t-1) + 2 u(t-1)
    sys = dict(a=np.array([-0.5]), b=np.array([2.0]), c1=np.array([-1.0, 1.0]), c2=np.array([1.0, 1.0]))
    v = np.array([0.0, 3.0, 2.5, 0.0, -3.0])
    y, u = simulate_numpy(sys, v, np.array([0.1, 0.0, 0.0, 0.0, 0.0]))
    np.testing.assert_allclose(u, [0.0, 2.0, 2.0, 1.0, -2.0])
    np.testing.assert_allclose(y, [0.1, 0.05, 4.025, 6.0125, 5.00625])
    yhat = predict_numpy(sys, v, y)
    np.testing.assert_allclose(y - yhat, [0.1, 0.0, 0.0, 0.0, 0.0], atol=1e-14)


def test_simulate_numpy_agrees_with_hbjax():
    rng = np.random.default_rng(7)
    N = 400
    for i in range(50):
        sys = random_paper_system(rng) if i < 40 else random_closing_loop_system(rng)
        kind = INPUT_KINDS[i % len(INPUT_KINDS)]
        scale = sys.get("scale", 2.0 * sys["h_m"]) * rng.uniform(0.5, 1.1)
        v = random_input(rng, kind, N, scale)
        y_free, _ = simulate_numpy(sys, v)
        xi = 0.03 * np.ptp(y_free) * rng.normal(size=N)
        y, _ = simulate_numpy(sys, v, xi)
        model = to_hbjax(sys)
        y_hb = np.asarray(hbjax.simulate(model, v, xi))
        tol = 1e-10 * max(1.0, np.max(np.abs(y)))
        assert np.max(np.abs(y - y_hb)) <= tol, (i, kind)
        yhat_hb = np.asarray(hbjax.predict(model, v, y))
        assert np.max(np.abs(predict_numpy(sys, v, y) - yhat_hb)) <= tol, (i, kind)
