"""`hbjax.fit` on records of every magnitude and operating point.

Random paper-class systems of the independent generator (``tests/generators/paper_class.py``)
under ordinary inputs (plateaus with sines, multisines, swept sines, filtered noise), T in
{300, 1500, 6000, 20000}, equation noise 0.2, 1 or 5 % of the output range; then the input
scaled by 10^-3-10^3 and, on half the records, moved by up to 20 half-ranges, and the output
scaled by 10^-3-10^3 and, on half the records, moved by up to 100 times its range.

Each fit (defaults, orders of the true system) is compared with the refinement of the true
system on the same record, and validated on a fresh input of the same kind clipped to the
recorded range (free-run fit against the noise-free true output). Both are scored the same
way: the one-step prediction errors on the estimation record from the initial state each
model's :func:`hbjax.compare` estimates (``horizon=1``), so that neither the solve's own
start (see :mod:`hbjax._identify.centring`) nor its coordinates decide. Categories:

- ``ok``: a success;
- ``local minimum``: a success whose sum of squared prediction errors exceeds the true
  system's refinement's by more than ``chi2_p(0.99)`` (in units of the noise variance);
- ``refused``: not a success (the reason is printed);
- ``error``: an exception (there should be none).

A success short of 90 % on validation is listed with the truth's own refinement's figure:
where that is as short, the record itself limits the model (noise integrated by slow poles,
short records), not the fit.

``python benchmarks/fit_offsets.py --seed 2 --records 30``
"""

import argparse
import os
import sys

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np
from scipy.stats import chi2

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
import hbjax  # noqa: E402
from tests.generators.paper_class import (  # noqa: E402
    INPUT_KINDS, random_input, random_paper_system, simulate_numpy, to_hbjax)

KINDS = tuple(k for k in INPUT_KINDS if k != "prbs_levels")  # ordinary, not designed, inputs


def one(rng, key):
    sys_ = random_paper_system(rng)
    kind = KINDS[rng.integers(len(KINDS))]
    T = int(rng.choice([300, 1500, 6000, 20000]))
    scale = 2.0 * sys_["h_m"]
    v = random_input(rng, kind, T, scale)
    v_val = np.clip(random_input(rng, kind, 2000, scale), v.min(), v.max())
    free, _ = simulate_numpy(sys_, v)
    level = float(rng.choice([0.002, 0.01, 0.05]))
    sigma = level * float(np.ptp(free))
    y, _ = simulate_numpy(sys_, v, sigma * rng.normal(size=T))
    v_gain, y_gain = 10 ** rng.uniform(-3, 3), 10 ** rng.uniform(-3, 3)
    v_shift = rng.uniform(-20, 20) * scale * (rng.random() < 0.5)
    y_shift = rng.uniform(-100, 100) * float(np.ptp(free)) * (rng.random() < 0.5)
    V, Y = v_gain * (v + v_shift), y_gain * (y + y_shift)
    truth_val, _ = simulate_numpy(sys_, v_val)
    V_val, Y_val = v_gain * (v_val + v_shift), y_gain * (truth_val + y_shift)
    orders = dict(na=len(sys_["a"]), nb=len(sys_["b"]), m=len(sys_["c1"]))
    row = dict(kind=kind, T=T, noise=level, v_shift=v_shift / scale,
               y_shift=y_shift / float(np.ptp(free)), **orders)
    try:
        res = hbjax.fit((V, Y), key=key, throw=False, progress=False, **orders)
    except Exception as err:  # noqa: BLE001 -- a study counts them
        return dict(row, category="error", message=f"{type(err).__name__}: {err}"[:160])
    # the true system on the same (scaled, moved) record, refined
    truth = to_hbjax(sys_)
    truth = hbjax.Hammerstein(
        hbjax.Backlash(*(_moved(c, v_gain, v_shift)
                         for c in (truth.backlash.c1, truth.backlash.c2))),
        hbjax.ARX(truth.arx.a, y_gain * np.asarray(truth.arx.b)))
    ref = hbjax.refine(hbjax.normalise_static_gain(_with_offset(truth, y_gain * y_shift)),
                       [(V, Y)], initial_state="estimate", throw=False)
    def sum_of_squares(model):
        return T * hbjax.compare(model, V, Y, horizon=1).rmse ** 2

    excess = (sum_of_squares(res.model) - sum_of_squares(ref.model)) / (y_gain * sigma) ** 2
    row.update(message=res.message[:100], excess=excess, truth_refined=ref.message[:40],
               validation=float(hbjax.compare(res.model, V_val, Y_val).fit),
               truth_validation=float(hbjax.compare(ref.model, V_val, Y_val).fit))
    ok = res.result == hbjax.RESULTS.successful
    p = sum(orders.values()) + orders["m"] - 1
    row["category"] = ("refused" if not ok else
                       "local minimum" if excess > chi2.ppf(0.99, p) else "ok")
    return row


def _moved(c, gain, shift):
    """Coefficients of ``P(v)`` as a polynomial in ``V = gain (v + shift)``."""
    c = np.asarray(c, float)
    out = np.zeros_like(c)
    for j, cj in enumerate(c):  # P = sum_j c_j (V / gain - shift)^j
        term = np.polynomial.polynomial.polypow([-shift, 1.0 / gain], j) if j else np.ones(1)
        out[:term.size] += cj * term
    return out


def _with_offset(model, offset):
    """The model whose output is moved by ``offset``: both branches by ``A(1) offset / B(1)``."""
    a, b = np.asarray(model.arx.a), np.asarray(model.arx.b)
    delta = (1.0 + a.sum()) * offset / b.sum()
    c1, c2 = np.asarray(model.backlash.c1).copy(), np.asarray(model.backlash.c2).copy()
    c1[0] += delta
    c2[0] += delta
    return hbjax.Hammerstein(hbjax.Backlash(c1, c2), model.arx)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--records", type=int, default=30)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    counts = {}
    for i in range(args.records):
        row = one(rng, jax.random.PRNGKey(i))
        counts[row["category"]] = counts.get(row["category"], 0) + 1
        short = ""
        if row.get("truth_refined", "success") != "success":
            short += f"  [the truth's refinement: {row['truth_refined']}]"
        if row["category"] == "ok" and row["validation"] < 90:
            short = f"  [short: the truth's own refinement validates at {row['truth_validation']:.1f} %]"
        print(f"{i:3d} {row['kind']:14s} T={row['T']:5d} na={row['na']} m={row['m']} "
              f"noise={row['noise']:<5} v moved {row['v_shift']:6.2f} half-ranges, y moved "
              f"{row['y_shift']:7.2f} ranges: {row['category']:13s} "
              f"{row.get('validation', np.nan):7.2f} % excess {row.get('excess', np.nan):8.2f} "
              f"{row['message'][:50] if row['category'] != 'ok' else ''}{short}", flush=True)
    print(f"seed {args.seed}, {args.records} records:", counts)


if __name__ == "__main__":
    main()
