"""One run of the paper-mode study of ``benchmarks/identify_random.py`` rebuilt from its
``(system, noise level, draw)``: the random paper-class system of
:mod:`tests.generators.paper_class` and its three noisy experiments, drawn in the study's
order (one generator per system, one per run in the order level, draw). The experiments'
inputs are the package's :class:`hbjax.GiriDesign` signals, as the study applies them;
everything random comes from the independent generator."""

import numpy as np

import hbjax

from .paper_class import random_paper_system, simulate_numpy


def paper_records(sys_, rng, level, T):
    """``(design, records, sigma)``: the paper's three experiments of ``T`` samples for the
    system ``sys_`` with white equation noise of std ``level`` x the range of the
    noise-free outputs, drawn from ``rng``."""
    design = hbjax.GiriDesign(n=sys_["n"], m=sys_["m"], h_m=sys_["h_m"])
    inputs = [np.asarray(f(T)) for f in (design.constant_input, design.binary_input,
                                         design.staircase_input)]
    free = [simulate_numpy(sys_, v)[0] for v in inputs]
    sigma = level * float(np.ptp(np.concatenate(free)))
    ys = [simulate_numpy(sys_, v, sigma * rng.normal(size=T))[0] for v in inputs]
    return design, list(zip(inputs, ys)), sigma


def reproduce(system, level, draw, *, seed, levels, draws, T):
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
                return (sys_, *paper_records(sys_, run_rng, level, T))
    raise ValueError(f"no run ({system}, {level}, {draw}) in levels {levels} x {draws} draws")
