"""Simulator throughput: hbjax (jit + vmap of a lax.scan over time-major arrays) vs a
Numba @njit loop (single thread) vs a NumPy loop over time vectorised across the batch.

Run: ``.venv/bin/python benchmarks/simulate.py [--batch 1000 --length 10000]``.
"""

import argparse
import os
import time

import jax
jax.config.update("jax_enable_x64", True)  # the estimators and the peers compare in float64
import numba
import numpy as np

import hbjax

from _machine import describe, write_section


@numba.njit(cache=False)
def numba_simulate(c1, c2, a, b, V, X):
    """Same recursion as hbjax.simulate; (B, T) layout so each trajectory is contiguous."""
    B, T = V.shape
    Y = np.zeros((B, T))
    na, nb, m = a.shape[0], b.shape[0], c1.shape[0]
    for k in range(B):
        u_hist = np.zeros(T)
        u_prev = 0.0
        for t in range(T):
            v = V[k, t]
            p1 = c1[m - 1]
            p2 = c2[m - 1]
            for i in range(m - 2, -1, -1):
                p1 = p1 * v + c1[i]
                p2 = p2 * v + c2[i]
            lo, hi = min(p1, p2), max(p1, p2)
            acc = X[k, t]
            for i in range(na):
                if t - 1 - i >= 0:
                    acc -= a[i] * Y[k, t - 1 - i]
            for i in range(nb):
                if t - 1 - i >= 0:
                    acc += b[i] * u_hist[t - 1 - i]
            Y[k, t] = acc
            u_prev = min(max(u_prev, lo), hi)
            u_hist[t] = u_prev
    return Y


def numpy_simulate(c1, c2, a, b, V, X):
    """Loop over time, vectorised across the batch (time-major (T, B))."""
    T, B = V.shape
    Y = np.zeros((T, B))
    U = np.zeros((T, B))
    u_prev = np.zeros(B)
    for t in range(T):
        v = V[t]
        p1 = np.polyval(c1[::-1], v)
        p2 = np.polyval(c2[::-1], v)
        acc = X[t].copy()
        for i in range(len(a)):
            if t - 1 - i >= 0:
                acc -= a[i] * Y[t - 1 - i]
        for i in range(len(b)):
            if t - 1 - i >= 0:
                acc += b[i] * U[t - 1 - i]
        Y[t] = acc
        u_prev = np.minimum(np.maximum(u_prev, np.minimum(p1, p2)), np.maximum(p1, p2))
        U[t] = u_prev
    return Y


def best_of(fn, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--batch", type=int, default=1000)
    parser.add_argument("--length", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-write", action="store_true")
    args = parser.parse_args()
    B, T = args.batch, args.length
    model = hbjax.default_system()
    c1, c2 = np.asarray(model.backlash.c1), np.asarray(model.backlash.c2)
    a, b = np.asarray(model.arx.a), np.asarray(model.arx.b)
    rng = np.random.default_rng(0)
    V = np.repeat(rng.uniform(-8, 8, (T // 10 + 1, B)), 10, axis=0)[:T]
    X = 0.5 * rng.normal(size=(T, B))
    Vj, Xj = jax.device_put(V), jax.device_put(X)

    sim = jax.jit(jax.vmap(hbjax.simulate, in_axes=(None, 1, 1), out_axes=1))
    start = time.perf_counter()
    compiled = sim.lower(model, Vj, Xj).compile()
    compile_s = time.perf_counter() - start
    y_jax = np.asarray(compiled(model, Vj, Xj))
    t_jax = best_of(lambda: compiled(model, Vj, Xj).block_until_ready(), args.repeats)

    # The floor for any simulator of this size: one pass that reads v and xi and writes y,
    # with no recursion at all. It bounds the attainable speed-up over the NumPy loop.
    floor = jax.jit(lambda V, X: V + X)
    floor(Vj, Xj).block_until_ready()
    t_floor = best_of(lambda: floor(Vj, Xj).block_until_ready(), args.repeats)

    Vt, Xt = np.ascontiguousarray(V.T), np.ascontiguousarray(X.T)
    start = time.perf_counter()
    y_nb = numba_simulate(c1, c2, a, b, Vt, Xt).T
    numba_compile_s = time.perf_counter() - start
    t_nb = best_of(lambda: numba_simulate(c1, c2, a, b, Vt, Xt), args.repeats)

    # The NumPy loop is slow: time a tenth of the record and scale (linear in T).
    T_np = max(T // 10, 100)
    y_np = numpy_simulate(c1, c2, a, b, V[:T_np], X[:T_np])
    t_np = best_of(lambda: numpy_simulate(c1, c2, a, b, V[:T_np], X[:T_np]), 2) * T / T_np

    # Orders are static: the scan body is straight-line code for any n, so the cost per
    # sample should grow only with the arithmetic (a few multiply-adds per lag).
    orders = []
    for n in (1, 4, 8):
        stable = np.poly(np.full(n, 0.5))[1:]  # A(q^-1) with n poles at 0.5
        model_n = hbjax.Hammerstein(model.backlash, hbjax.ARX(stable, np.full(n, 1.0 / n)))
        comp_n = sim.lower(model_n, Vj, Xj).compile()
        t_n = best_of(lambda: comp_n(model_n, Vj, Xj).block_until_ready(), args.repeats)
        a_n, b_n = np.asarray(model_n.arx.a), np.asarray(model_n.arx.b)
        numba_simulate(c1, c2, a_n, b_n, Vt, Xt)
        t_nb_n = best_of(lambda: numba_simulate(c1, c2, a_n, b_n, Vt, Xt), args.repeats)
        orders.append((n, t_n, t_nb_n))

    err_nb = np.max(np.abs(y_jax - y_nb))
    err_np = np.max(np.abs(y_jax[:T_np] - y_np))
    assert err_nb < 1e-9 and err_np < 1e-9, (err_nb, err_np)
    samples = B * T
    rows = [
        ("hbjax jit(vmap(simulate)), time-major", t_jax),
        ("Numba @njit loop, 1 thread", t_nb),
        (f"NumPy loop over time (timed on T={T_np}, scaled)", t_np),
        ("memory floor: one jitted pass y = v + xi, no recursion", t_floor),
    ]
    lines = [
        f"Machine: {describe()}; 1-minute load average {os.getloadavg()[0]:.1f} at the end "
        f"(on {os.cpu_count()} cores).",
        f"Problem: B = {B} trajectories x T = {T} samples, float64, n = 2, m = 3 (default system); best of {args.repeats}.",
        "",
        "| implementation | wall time (s) | Msamples/s | hbjax speed-up |",
        "|---|---|---|---|",
    ]
    for name, t in rows:
        lines.append(f"| {name} | {t:.3f} | {samples / t / 1e6:.1f} | {t / t_jax:.2f}x |")
    lines += [
        "",
        f"Compile time: hbjax {compile_s:.2f} s (XLA), Numba {numba_compile_s:.2f} s (first call incl. JIT).",
        "",
        "Other orders n = na = nb (same input and noise; time in s, hbjax vs the Numba loop): "
        + "; ".join(f"n = {n}: {tj:.3f} vs {tn:.3f} ({tn / tj:.2f}x)" for n, tj, tn in orders)
        + ".",
        "",
        f"Agreement: max |y_hbjax - y_numba| = {err_nb:.1e}, max |y_hbjax - y_numpy| = {err_np:.1e}.",
        f"Targets: >= 1.5x Numba (measured {t_nb / t_jax:.2f}x), >= 50x NumPy (measured {t_np / t_jax:.1f}x).",
        f"Even the memory floor (reading v and xi and writing y once, {t_floor * 1e3:.1f} ms) is only "
        f"{t_np / t_floor:.1f}x the NumPy loop: vectorised across B = {B} trajectories the NumPy loop "
        "already streams whole rows, so a 50x ratio is out of reach for any implementation on this "
        f"machine; hbjax runs at {t_floor / t_jax:.2f} of the floor's speed.",
    ]
    report = "\n".join(lines)
    print(report)
    if not args.no_write:
        write_section("Simulator throughput (benchmarks/simulate.py)", report)


if __name__ == "__main__":
    main()
