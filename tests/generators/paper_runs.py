"""One run of the paper-mode study of ``benchmarks/identify_random.py`` rebuilt from its
``(system, noise level, draw)``: the random paper-class system of
:mod:`tests.generators.paper_class` and its three noisy experiments, drawn in the study's
order (one generator per system, one per run in the order level, draw). The experiments'
inputs are the package's :class:`hbjax.GiriDesign` signals, as the study applies them;
everything random comes from the independent generator."""

import numpy as np

import hbjax

from .paper_class import random_paper_system, simulate_numpy


def noise_gain(a, n=100_000):
    """``||1/A||_2``: the output's noise std per unit of equation-noise std (the root sum of
    squares of ``1/A``'s impulse response, summed until it has decayed)."""
    a = np.asarray(a, float)
    h = np.zeros(n)
    h[0] = 1.0
    for t in range(1, n):
        k = min(len(a), t)
        h[t] = -np.dot(a[:k], h[t - 1::-1][:k])
        if t > 50 and abs(h[t]) < 1e-13 * abs(h[:t]).max():
            break
    return float(np.sqrt(np.sum(h * h)))


def paper_records(sys_, rng, level, T, *, noise_at="equation"):
    """``(design, records, sigma)``: the paper's three experiments of ``T`` samples for the
    system ``sys_`` with white equation noise ``xi`` drawn from ``rng``; ``sigma`` is its std.

    `noise_at`: ``"equation"``, ``sigma = level`` x the range of the noise-free outputs;
    ``"output"``, the noise's part of the output (``xi`` through ``1/A``) has that std, so
    ``sigma = level x range / ||1/A||_2`` (:func:`noise_gain`: a slow ``A`` integrates the
    equation noise, and at the same ``sigma`` its output is mostly noise)."""
    if noise_at not in ("equation", "output"):
        raise ValueError(f"noise_at must be 'equation' or 'output', got {noise_at!r}")
    design = hbjax.GiriDesign(n=sys_["n"], m=sys_["m"], h_m=sys_["h_m"])
    inputs = [np.asarray(f(T)) for f in (design.constant_input, design.binary_input,
                                         design.staircase_input)]
    free = [simulate_numpy(sys_, v)[0] for v in inputs]
    sigma = level * float(np.ptp(np.concatenate(free)))
    if noise_at == "output":
        sigma /= noise_gain(sys_["a"])
    ys = [simulate_numpy(sys_, v, sigma * rng.normal(size=T))[0] for v in inputs]
    return design, list(zip(inputs, ys)), sigma


def reproduce(system, level, draw, *, seed, levels, draws, T, noise_at="equation"):
    """``(system, design, records, sigma)`` of run ``(system, level, draw)`` of the study
    with `seed`, noise `levels` and `draws` per level (:func:`paper_records`)."""
    rng = np.random.default_rng(seed)
    for _ in range(system + 1):
        sys_rng = np.random.default_rng(rng.integers(2**63))
        sys_ = random_paper_system(sys_rng)
    for lv in levels:
        for d in range(draws):
            run_rng = np.random.default_rng(sys_rng.integers(2**63))
            if lv == level and d == draw:
                return (sys_, *paper_records(sys_, run_rng, level, T, noise_at=noise_at))
    raise ValueError(f"no run ({system}, {level}, {draw}) in levels {levels} x {draws} draws")


def ordinary_record_and_start(rng, *, T, kind, m=None, noise=0.02, c_off=0.1, a_off=0.05):
    """``(system, v, y, start)``: a random paper-class system (branch degree `m`, random
    if ``None``), one ordinary input of ``T`` samples of `kind`
    (:data:`tests.generators.paper_class.INPUT_KINDS`) with peak ``1.5 h_m``, equation
    noise of std `noise` x the noise-free output's spread, and a start off the truth: the
    branch coefficients by up to `c_off`, ``a`` by up to `a_off`, ``b`` by up to `c_off`
    (relative, uniform, each coefficient on its own)."""
    from .paper_class import random_input, to_hbjax

    sys_ = random_paper_system(rng, m=m)
    v = random_input(rng, kind, T, 1.5 * sys_["h_m"])
    y0, _ = simulate_numpy(sys_, v)
    y, _ = simulate_numpy(sys_, v, noise * np.std(y0) * rng.standard_normal(v.size))
    true = to_hbjax(sys_)

    def off(x, size):
        return np.asarray(x) * rng.uniform(1 - size, 1 + size, np.shape(x))

    start = hbjax.Hammerstein(
        hbjax.Backlash(off(true.backlash.c1, c_off), off(true.backlash.c2, c_off)),
        hbjax.ARX(off(true.arx.a, a_off), off(true.arx.b, c_off)))
    return sys_, v, y, start


def output_unit_weights(result, unit):
    """Per flattened parameter (``a, b, c1, c2``) of a refinement `result`, the factor an
    output unit puts on it: ``b`` carries the unit in the paper's gauge
    (``P2(-h_m) - P1(h_m) = 1`` fixes the branches), the branches in the static-gain gauge
    (``B(1) = 1`` fixes ``b``); ``a`` never."""
    na, nb, m = result.model.arx.na, result.model.arx.nb, result.model.backlash.m
    w = np.ones(na + nb + 2 * m)
    if result.gauge == "paper":
        w[na:na + nb] = unit
    else:
        w[na + nb:] = unit
    return w
