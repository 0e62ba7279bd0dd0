"""Independent random HB-Hammerstein test systems, inputs and a plain-NumPy simulator.

Written from the model definition alone (``/work/shared/paper/NOTES.md``, ``docs/conventions.md``),
not from the package's own generators, so that studies built on it test the identification on
systems the package was not shaped on.

A system is a plain ``dict``:

- ``a`` (``[a_1..a_na]``), ``b`` (``[b_1..b_nb]``): ARX block
  ``y(t) = -sum a_i y(t-i) + sum b_j u(t-j) + xi(t)``;
- ``c1``, ``c2``: branches ``P1``, ``P2`` in ascending powers (``m`` coefficients each);
- ``h_m``: the design amplitude; ``n = max(na, nb)``, ``m``, ``na``, ``nb``, ``delay``;
- paper class: ``gap_rel`` (the band's mean width over the output range on
  ``[-2 h_m, 2 h_m]``), ``out_range``;
- closing loop: ``scale`` (input amplitude), ``v_meet`` (where the branches meet or cross),
  ``kind`` (``"touch"`` or ``"cross"``).

Everything here is NumPy; only :func:`to_hbjax` touches ``hbjax``.
"""

from __future__ import annotations

import numpy as np


INPUT_KINDS = ("plateaus_sines", "multisine", "prbs_levels", "swept_sine", "filtered_noise")

# Grid used to check a draw's promises on [-2 h_m, 2 h_m] (in x = v / h_m).
_GRID = np.linspace(-2.0, 2.0, 2001)


# --------------------------------------------------------------------------- polynomials


def polyval_asc(c, v):
    """``c[0] + c[1] v + ... + c[m-1] v^(m-1)`` (Horner, ascending coefficients)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros_like(v)
    for coef in np.asarray(c, dtype=float)[::-1]:
        out = out * v + coef
    return out


def _scale_coefficients(p, h_m, s):
    """Coefficients of ``s * p(v / h_m)`` from those of ``p(x)`` (ascending)."""
    p = np.asarray(p, dtype=float)
    return s * p / float(h_m) ** np.arange(len(p))


def _derivative_asc(c):
    c = np.asarray(c, dtype=float)
    if len(c) == 1:
        return np.zeros(1)
    return c[1:] * np.arange(1, len(c))


# --------------------------------------------------------------------------- linear block


def _random_poles(rng, na):
    """``na`` poles, real or complex-conjugate pairs, radius in [0.2, 0.95]."""
    poles = []
    pairs = rng.integers(0, na // 2 + 1)
    for _ in range(pairs):
        r = rng.uniform(0.2, 0.95)
        phi = rng.uniform(0.15, np.pi - 0.15)
        poles += [r * np.exp(1j * phi), r * np.exp(-1j * phi)]
    while len(poles) < na:
        poles.append(rng.choice([-1.0, 1.0]) * rng.uniform(0.2, 0.95))
    return np.array(poles)


def random_arx(rng, na, *, nb=None, max_delay=None):
    """A stable ``A`` (order ``na``) and a ``B`` (``nb = na`` by default) with ``B(1) != 0``.

    ``B`` may start with zeros (a delay of up to ``nb - 1`` samples); its zeros stay away from
    the poles (A2, coprime) and the static gain ``|B(1) / A(1)|`` is log-uniform in [0.3, 3].
    """
    nb = na if nb is None else nb
    max_delay = nb - 1 if max_delay is None else min(max_delay, nb - 1)
    for _ in range(1000):
        poles = _random_poles(rng, na)
        a = np.real(np.poly(poles))[1:]
        delay = int(rng.integers(0, max_delay + 1)) if rng.uniform() < 0.35 else 0
        free = rng.normal(size=nb - delay)
        b = np.concatenate([np.zeros(delay), free])
        if abs(b.sum()) < 0.25 * np.abs(b).sum():
            continue  # A5 with a margin
        if nb - delay > 1:
            zeros = np.roots(free)
            if np.min(np.abs(zeros[:, None] - poles[None, :])) < 0.08:
                continue  # A2 with a margin
        gain = np.exp(rng.uniform(np.log(0.3), np.log(3.0)))
        b = b * gain * abs((1.0 + a.sum()) / b.sum())
        return a, b, delay
    raise RuntimeError("no linear block found")  # pragma: no cover


# --------------------------------------------------------------------------- paper class


def _monotone_base(rng, m):
    """``g(x) = x + sum_{k>=2} q_k x^k`` with ``g' >= 0.2`` on [-2, 2]."""
    for _ in range(1000):
        q = np.zeros(m)
        q[1] = 1.0
        for k in range(2, m):
            q[k] = rng.uniform(-1.0, 1.0) * 0.6 / 2.0 ** (k - 1)
        if np.min(polyval_asc(_derivative_asc(q), _GRID)) >= 0.2:
            return q
    raise RuntimeError("no monotone base found")  # pragma: no cover


def _shape(rng, m, amplitude):
    """``1 + sum_{k>=1} e_k x^k``, ``|e_k| <= amplitude / 2^k`` (a smooth positive-ish bump)."""
    e = np.zeros(m)
    e[0] = 1.0
    for k in range(1, m):
        e[k] = rng.uniform(-amplitude, amplitude) / 2.0**k
    return e


def paper_violations(sys, *, margin=0.01):
    """Which promises of :func:`random_paper_system` ``sys`` breaks (empty list: none).

    Checked in ``x = v / h_m`` on a dense grid of [-2, 2]: A3 (stable ``A``), A5 (``B(1)``
    not small), non-crossing with a margin (``P2 - P1 >= margin * range``: ``P1`` the lower
    edge), both branches increasing, A4 (each branch has its zero in ``(-h_m, h_m)``), the gap
    crossed by the +-h_m swing (``P1(h_m) - P2(-h_m) >= margin * range``), and the staircase:
    the play operator driven by ``v2`` then ``v3`` sits on ``P1`` at every rising level and on
    ``P2`` at every falling level.
    """
    bad = []
    a, b = np.asarray(sys["a"], float), np.asarray(sys["b"], float)
    c1, c2, h_m, m = np.asarray(sys["c1"], float), np.asarray(sys["c2"], float), sys["h_m"], sys["m"]
    if len(a) and np.max(np.abs(np.roots(np.concatenate([[1.0], a])))) >= 0.96:
        bad.append("A3: A not stable with margin")
    if abs(b.sum()) < 1e-3 * max(np.abs(b).sum(), 1e-300):
        bad.append("A5: B(1) = 0")
    v = _GRID * h_m
    p1, p2 = polyval_asc(c1, v), polyval_asc(c2, v)
    out_range = max(p1.max(), p2.max()) - min(p1.min(), p2.min())
    if np.min(p2 - p1) < margin * out_range:
        bad.append("branches cross or touch on [-2h_m, 2h_m]")
    if np.min(np.diff(p1)) <= 0 or np.min(np.diff(p2)) <= 0:
        bad.append("a branch is not increasing on [-2h_m, 2h_m]")
    for name, c in (("P1", c1), ("P2", c2)):
        if not polyval_asc(c, -h_m) < 0 < polyval_asc(c, h_m):
            bad.append(f"A4: {name} has no zero in (-h_m, h_m)")
    if polyval_asc(c1, h_m) - polyval_asc(c2, -h_m) < margin * out_range:
        bad.append("A4: +-h_m swing does not cross the gap (P1(h_m) <= P2(-h_m))")
    if max(abs(c1[-1]), abs(c2[-1])) * (2.0 * h_m) ** (m - 1) < 1e-3 * out_range:
        bad.append("A4: degree lower than m - 1")
    if not _staircase_on_branches(c1, c2, h_m, m, sys["n"]):
        bad.append("staircase: plateau output not on P1 (rising) / P2 (falling)")
    return bad


def design_levels(h_m, m):
    """The 2m plateau levels of eq. (32) actually applied (NOTES.md), j = 0..2m-1."""
    j = np.arange(2 * m)
    return np.where(j < m, h_m + j * h_m / m, -h_m - (j - m) * h_m / m)


def _staircase_on_branches(c1, c2, h_m, m, n):
    """Play operator under v1, v2 then two periods of v3 (written from NOTES.md)."""
    levels = design_levels(h_m, m)
    v = np.concatenate([np.zeros(1), np.full(4, h_m), np.tile([h_m, -h_m], 3), np.repeat(np.tile(levels, 2), n + 1)])
    u = _play(c1, c2, v)
    tail = u[-2 * len(levels) * (n + 1) :].reshape(2 * len(levels), n + 1)
    want = np.where(np.tile(levels, 2) > 0, polyval_asc(c1, np.tile(levels, 2)), polyval_asc(c2, np.tile(levels, 2)))
    scale = max(np.max(np.abs(want)), 1e-300)
    return bool(np.all(np.abs(tail - want[:, None]) <= 1e-12 * scale))


def random_paper_system(rng, *, n=None, m=None):
    """A random system of the paper's class (assumptions A2-A5, NOTES.md), as a ``dict``.

    - ``A``: order ``na = n`` (1-4 if not given), real or complex poles of radius 0.2-0.95;
      ``B``: ``nb = na`` coefficients, sometimes leading zeros (a delay), ``B(1) != 0``.
    - branches (``m`` = 2-5 coefficients if not given) in ``x = v / h_m``:
      ``P1 = g - d/2 + o``, ``P2 = g + d/2 + o`` with ``g`` increasing and the band ``d``
      positive on [-2, 2]; ``h_m`` log-uniform in [0.3, 10], output scale log-uniform in
      [0.2, 20]; the mean band width is log-uniform from 2 % to 45 % of the output range
      on [-2 h_m, 2 h_m] (45 % is about as wide as the +-h_m swing still crosses).
    - the draw is kept only if :func:`paper_violations` is empty (non-crossing with a 1 %
      margin on a 2001-point grid, gap crossed by the swing, staircase on the branches).
    """
    na = int(rng.integers(1, 5)) if n is None else int(n)
    m = int(rng.integers(2, 6)) if m is None else int(m)
    a, b, delay = random_arx(rng, na)
    for _ in range(10_000):
        h_m = float(np.exp(rng.uniform(np.log(0.3), np.log(10.0))))
        s = float(np.exp(rng.uniform(np.log(0.2), np.log(20.0))))
        g = _monotone_base(rng, m)
        g_range = polyval_asc(g, 2.0) - polyval_asc(g, -2.0)
        gap_rel = float(np.exp(rng.uniform(np.log(0.02), np.log(0.45))))
        d = _shape(rng, m, 0.5)
        d = d * gap_rel * g_range / np.mean(polyval_asc(d, _GRID))
        offset = np.zeros(m)
        offset[0] = rng.uniform(-0.3, 0.3) * polyval_asc(g, 1.0)
        p1, p2 = g - d / 2 + offset, g + d / 2 + offset
        sys = dict(
            a=a, b=b, c1=_scale_coefficients(p1, h_m, s), c2=_scale_coefficients(p2, h_m, s),
            h_m=h_m, n=na, m=m, na=na, nb=len(b), delay=delay,
        )
        if np.min(polyval_asc(d, _GRID)) <= 0 or paper_violations(sys, margin=0.01):
            continue
        v = _GRID * h_m
        lo, hi = polyval_asc(sys["c1"], v), polyval_asc(sys["c2"], v)
        sys["out_range"] = float(max(hi.max(), lo.max()) - min(hi.min(), lo.min()))
        sys["gap_rel"] = float(np.mean(hi - lo) / sys["out_range"])
        return sys
    raise RuntimeError("no paper-class system found")  # pragma: no cover


# --------------------------------------------------------------------------- closing loops


def random_closing_loop_system(rng, *, n=None, m=None, kind=None):
    """A system whose branches meet (``"touch"``) or cross (``"cross"``) inside the input range.

    The input amplitude ``scale`` is uniform in [2, 8]; the branches meet at
    ``v_meet = +-(0.5..0.85) scale`` (e.g. at -4.5 while the input spans +-6). ``"touch"``:
    the band ``d(v) = w ((v - v_meet)/scale)^2 (1 + ...)`` closes to zero and reopens
    (``m >= 3``); ``"cross"``: ``d`` is linear in ``v - v_meet``, the branches swap beyond
    ``v_meet`` and the loop closes there. ``h_m = scale / 2`` so that [-2 h_m, 2 h_m] is the
    input range. The branches are increasing on it.
    """
    na = int(rng.integers(1, 4)) if n is None else int(n)
    if kind is None:
        kind = "touch" if (m is None or m >= 3) and rng.uniform() < 0.5 else "cross"
    if m is None:
        m = int(rng.integers(3, 6)) if kind == "touch" else int(rng.integers(2, 5))
    if kind == "touch" and m < 3:
        raise ValueError("a touching band needs m >= 3")
    a, b, delay = random_arx(rng, na)
    for _ in range(10_000):
        scale = float(rng.uniform(2.0, 8.0))
        s = float(np.exp(rng.uniform(np.log(0.3), np.log(5.0))))
        x_meet = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 0.85))  # in x = v / scale
        grid = np.linspace(-1.0, 1.0, 2001)
        g = _monotone_base(rng, m)  # increasing on [-2, 2], so on [-1, 1]
        w = float(np.exp(rng.uniform(np.log(0.1), np.log(0.8))))
        if kind == "touch":
            d = np.zeros(m)
            d[:3] = [x_meet**2, -2.0 * x_meet, 1.0]  # (x - x_meet)^2
        else:
            d = np.zeros(m)
            d[:2] = [-x_meet, 1.0] if x_meet < 0 else [x_meet, -1.0]  # open on the wide side
        d = d * w / np.max(np.abs(polyval_asc(d, grid)))
        p1, p2 = g - d / 2, g + d / 2
        if np.min(np.diff(polyval_asc(p1, grid))) <= 0 or np.min(np.diff(polyval_asc(p2, grid))) <= 0:
            continue
        c1, c2 = _scale_coefficients(p1, scale, s), _scale_coefficients(p2, scale, s)
        return dict(
            a=a, b=b, c1=c1, c2=c2, h_m=scale / 2, n=na, m=m, na=na, nb=len(b), delay=delay,
            scale=scale, v_meet=x_meet * scale, kind=kind,
        )
    raise RuntimeError("no closing-loop system found")  # pragma: no cover


# --------------------------------------------------------------------------- inputs


def _peak_normalise(x, scale):
    x = np.asarray(x, float)
    return scale * x / max(np.max(np.abs(x)), 1e-300)


def random_input(rng, kind, N, scale):
    """An ordinary input of ``N`` samples with peak ``|v| <= scale`` (reached or nearly).

    - ``"plateaus_sines"``: random levels held 5-60 samples, interleaved with sine segments;
    - ``"multisine"``: 3-12 random frequencies in (0, 0.1] cycles/sample, random phases;
    - ``"prbs_levels"``: one of 3-7 random levels, switched at random instants
      (geometric holding times, at least 3 samples);
    - ``"swept_sine"``: a chirp from 1/1000 to 1/20 cycles/sample and back, repeated;
    - ``"filtered_noise"``: white noise through a random second-order low-pass.
    """
    N = int(N)
    if kind == "plateaus_sines":
        parts, total = [], 0
        while total < N:
            if rng.uniform() < 0.7:
                seg = np.full(int(rng.integers(5, 61)), rng.uniform(-1, 1))
            else:
                period = rng.uniform(20, 200)
                L = int(period * rng.uniform(0.5, 3))
                t = np.arange(max(L, 2))
                seg = rng.uniform(0.2, 1) * np.sin(2 * np.pi * t / period + rng.uniform(0, 2 * np.pi))
            parts.append(seg)
            total += len(seg)
        x = np.concatenate(parts)[:N]
    elif kind == "multisine":
        K = int(rng.integers(3, 13))
        f = rng.uniform(0.002, 0.1, K)
        t = np.arange(N)[:, None]
        x = np.sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi, K)), axis=1)
    elif kind == "prbs_levels":
        levels = rng.uniform(-1, 1, int(rng.integers(3, 8)))
        levels[np.argmax(np.abs(levels))] = np.sign(levels[np.argmax(np.abs(levels))])
        parts, total = [], 0
        p = rng.uniform(0.03, 0.3)
        while total < N:
            L = 3 + int(rng.geometric(p))
            parts.append(np.full(L, rng.choice(levels)))
            total += L
        x = np.concatenate(parts)[:N]
    elif kind == "swept_sine":
        period = int(rng.integers(600, 3000))
        t = np.arange(period)
        f0, f1 = 1e-3, 0.05
        half = period // 2
        f = np.concatenate([np.geomspace(f0, f1, half), np.geomspace(f1, f0, period - half)])
        phase = 2 * np.pi * np.cumsum(f)
        x = np.tile(np.sin(phase + rng.uniform(0, 2 * np.pi)), N // period + 1)[:N]
        del t
    elif kind == "filtered_noise":
        r = rng.uniform(0.7, 0.97)
        phi = rng.uniform(0.0, 0.3)
        a1, a2 = -2 * r * np.cos(phi), r * r
        e = rng.normal(size=N + 500)
        x = np.zeros(N + 500)
        for t in range(2, N + 500):
            x[t] = e[t] - a1 * x[t - 1] - a2 * x[t - 2]
        x = x[500:]
        x = np.clip(x / (2.5 * np.std(x)), -1, 1)
    else:
        raise ValueError(f"kind must be one of {INPUT_KINDS}, got {kind!r}")
    return _peak_normalise(x, scale)


# --------------------------------------------------------------------------- simulation


def _play(c1, c2, v, u0=0.0):
    """``u(t) = min(max(u(t-1), L(v(t))), H(v(t)))``, ``L/H = min/max(P1, P2)``, ``u(-1) = u0``."""
    p1, p2 = polyval_asc(c1, v), polyval_asc(c2, v)
    lo, hi = np.minimum(p1, p2), np.maximum(p1, p2)
    u = np.empty(len(v))
    state = float(u0)
    for t in range(len(v)):
        state = min(max(state, lo[t]), hi[t])
        u[t] = state
    return u


def simulate_numpy(sys, v, noise=None, *, u0=0.0):
    """Free run of the system in plain NumPy: the play operator, then the ARX equation error.

    ``y(t) = -sum_i a_i y(t-i) + sum_j b_j u(t-j) + xi(t)`` with zero initial conditions
    (``y(t) = u(t) = 0`` for ``t < 0``); ``noise`` is ``xi`` (an array) or ``None``.
    Returns ``(y, u)``.
    """
    v = np.asarray(v, dtype=float)
    a, b = np.asarray(sys["a"], float), np.asarray(sys["b"], float)
    xi = np.zeros(len(v)) if noise is None else np.asarray(noise, dtype=float)
    u = _play(sys["c1"], sys["c2"], v, u0)
    y = np.zeros(len(v))
    for t in range(len(v)):
        acc = xi[t]
        for i in range(min(len(a), t)):
            acc -= a[i] * y[t - 1 - i]
        for j in range(min(len(b), t)):
            acc += b[j] * u[t - 1 - j]
        y[t] = acc
    return y, u


def predict_numpy(sys, v, y, *, u0=0.0):
    """One-step-ahead prediction ``-sum a_i y(t-i) + sum b_j u(t-j)`` from measured ``y``."""
    a, b = np.asarray(sys["a"], float), np.asarray(sys["b"], float)
    y = np.asarray(y, dtype=float)
    u = _play(sys["c1"], sys["c2"], np.asarray(v, float), u0)
    T = len(y)
    yhat = np.zeros(T)
    for i in range(len(a)):
        yhat[i + 1 :] -= a[i] * y[: T - 1 - i]
    for j in range(len(b)):
        yhat[j + 1 :] += b[j] * u[: T - 1 - j]
    return yhat


def to_hbjax(sys):
    """``hbjax.Hammerstein(hbjax.Backlash(c1, c2), hbjax.ARX(a, b))`` for a system ``dict``."""
    import hbjax

    return hbjax.Hammerstein(
        hbjax.Backlash(c1=np.asarray(sys["c1"], float), c2=np.asarray(sys["c2"], float)),
        hbjax.ARX(a=np.asarray(sys["a"], float), b=np.asarray(sys["b"], float)),
    )


def random_differencing_system(rng, *, m=3):
    """A system whose linear block has almost no static gain: ``B = beta (1 - rho q^-1)``
    with ``1 - rho`` log-uniform in [1e-5, 1e-3] (``|B(1)| / sum |b|`` 5e-6 to 5e-4), the
    output a near-difference of the backlash output, as a friction force follows the
    velocity of a driven displacement. ``A`` stable of order 2 (poles 0.2-0.95), branches
    from :func:`random_paper_system` (``m`` coefficients); ``beta`` sets the output's
    scale near the branches'."""
    sys_ = random_paper_system(rng, n=2, m=m)
    rho = 1.0 - float(np.exp(rng.uniform(np.log(1e-5), np.log(1e-3))))
    beta = float(rng.choice([-1.0, 1.0]) * np.exp(rng.uniform(np.log(0.5), np.log(2.0))))
    sys_.update(b=np.array([beta, -beta * rho]), nb=2, delay=0)
    return sys_
