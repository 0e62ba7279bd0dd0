"""An independent concealed-effect generator for testing :func:`hbjax.diagnose` on data it
was not tuned on.

Written from the physical definitions of the effects only (``docs/diagnosis.md`` and the
docstrings of ``hbjax.EFFECTS``), in plain NumPy, with its own random base systems, its own
inputs and its own effect mechanisms (several of which are deliberately *not* the exact
parametric form the package fits: exponential thermal drift, compressive sensors, an extra
lag with a zero, friction inside the recursion, ...).

Base system (``docs/conventions.md``): play operator ``u(t) = min(max(u(t-1), L(v)), H(v))``
with ``L = min(P1, P2)``, ``H = max(P1, P2)``, ``u(-1) = 0``, then the ARX block
``y(t) = -sum_i a_i y(t-i) + sum_j b_j u(t-j) + xi(t)`` with zero initial conditions.
``xi`` is white equation error (the paper's noise model) scaled so that its contribution to
the output has a standard deviation of ``noise_fraction`` (0.5-5%) of the output spread,
the spread being the 5-95% quantile range of the noise-free nominal output.

Effect sizes: every effect has one strength knob. For continuous knobs the knob is set by
bisection so that the RMS change of the noise-free output, ``||y_effect - y_nominal|| /
sqrt(T)``, equals ``ratio`` times the output noise standard deviation, with ``ratio``
log-uniform in ``[RATIO_MIN, RATIO_MAX]`` ("just detectable" to "strong"); ``size`` is the
position of ``ratio`` in that range (0 to 1). ``colored_noise`` (no deterministic change)
uses the noise pole radius instead; ``extra_delay`` the delay, raised until the ratio
reaches ``RATIO_MIN``.

Entry point: :func:`concealed_case`.
"""

from __future__ import annotations

import math

import numpy as np

# Effects the package lists in hbjax.EFFECTS, plus the ones being added to it.
PACKAGE_EFFECTS = (
    "parameter_mismatch", "output_saturation", "input_saturation", "extra_delay",
    "unmodeled_dynamics", "colored_noise", "offset_drift", "parameter_change",
    "periodic_disturbance", "output_nonlinearity", "coulomb_friction", "branch_degree",
)
NEW_EFFECTS = ("level_dependent_dynamics", "harmonic_distortion", "missing_input")
ALL_EFFECTS = PACKAGE_EFFECTS + NEW_EFFECTS
INPUT_KINDS = ("plateaus", "multisine", "prbs", "swept", "noise")

RATIO_MIN, RATIO_MAX = 0.7, 7.0      # RMS output change / output noise std
NOISE_MIN, NOISE_MAX = 0.005, 0.05   # output noise std / output spread
N_MIN, N_MAX = 1000, 8000


# ----------------------------------------------------------------------------- base system
def _poly_from_roots(roots):
    return np.real(np.poly(roots))[1:]


def random_poles(rng, na):
    """``na`` stable discrete poles: real ones and complex pairs, radius 0.3-0.95."""
    n_pairs = rng.integers(0, na // 2 + 1)
    poles = []
    for _ in range(n_pairs):
        r, w = rng.uniform(0.5, 0.95), rng.uniform(0.05, 1.2)
        poles += [r * np.exp(1j * w), r * np.exp(-1j * w)]
    while len(poles) < na:
        poles.append(rng.uniform(0.3, 0.95) * (1 if rng.random() < 0.85 else -1))
    return np.asarray(poles, complex)


def random_base(rng, *, na=None, nb=None, m=None):
    """A random HB-Hammerstein system as a dict of NumPy arrays (static gain B(1)/A(1) = 1)."""
    na = int(rng.integers(1, 5)) if na is None else na
    nb = int(rng.integers(1, 5)) if nb is None else nb
    m = int(rng.integers(2, 5)) if m is None else m
    poles = random_poles(rng, na)
    a = _poly_from_roots(poles)
    while True:
        b = rng.normal(size=nb)
        b[0] = np.sign(b[0] or 1.0) * max(abs(b[0]), 0.5 * np.max(np.abs(b)))
        if abs(b.sum()) > 0.4 * np.abs(b).sum():  # assumption A5 with a margin
            break
    b = b * (1.0 + a.sum()) / b.sum()
    amp = float(rng.uniform(1.0, 10.0))          # input amplitude
    slope = float(rng.uniform(0.5, 2.0))
    half = float(rng.uniform(0.05, 0.5)) * amp   # half band width, in input units
    grid = np.linspace(-1.3 * amp, 1.3 * amp, 201)
    for _ in range(100):
        c1 = np.zeros(m)
        c2 = np.zeros(m)
        c1[:2] = [-slope * half, slope]
        c2[:2] = [slope * half, slope]
        for k in range(2, m):
            common = rng.uniform(-0.15, 0.15) * slope / amp ** (k - 1)
            c1[k] = common * (1 + rng.uniform(-0.3, 0.3))
            c2[k] = common * (1 + rng.uniform(-0.3, 0.3))
        if _branches_ok(c1, c2, grid, slope, half):
            break
    return dict(a=a, b=b, c1=c1, c2=c2, poles=poles, na=na, nb=nb, m=m, amp=amp,
                slope=slope, half=half)


def _branches_ok(c1, c2, grid, slope, half):
    p1, p2 = np.polyval(c1[::-1], grid), np.polyval(c2[::-1], grid)
    d1 = np.polyval(np.polyder(c1[::-1]), grid) if len(c1) > 1 else 0 * grid
    d2 = np.polyval(np.polyder(c2[::-1]), grid) if len(c2) > 1 else 0 * grid
    return bool(np.all(p2 - p1 > 0.5 * slope * half) and np.all(d1 > 0.2 * slope)
                and np.all(d2 > 0.2 * slope))


def hammerstein(base):
    """The base system as an :class:`hbjax.Hammerstein` (the only hbjax use here)."""
    import hbjax

    return hbjax.Hammerstein(hbjax.Backlash(c1=np.asarray(base["c1"]), c2=np.asarray(base["c2"])),
                             hbjax.ARX(a=np.asarray(base["a"]), b=np.asarray(base["b"])))


# ----------------------------------------------------------------------------- simulators
def play(v, c1, c2, u0=0.0):
    """Generalised play operator between the branches P1 (coefficients c1) and P2."""
    p1 = np.polyval(np.asarray(c1, float)[::-1], v)
    p2 = np.polyval(np.asarray(c2, float)[::-1], v)
    lo, hi = np.minimum(p1, p2).tolist(), np.maximum(p1, p2).tolist()
    u, s = [0.0] * len(lo), float(u0)
    for t in range(len(lo)):
        s = min(max(s, lo[t]), hi[t])
        u[t] = s
    return np.asarray(u)


def arx(u, xi, a, b, *, delay=0):
    """``A y = B q^-delay u + xi`` with zero initial conditions (plain loop)."""
    a, b = [float(x) for x in a], [float(x) for x in b]
    u, xi = np.asarray(u, float).tolist(), np.asarray(xi, float).tolist()
    y = [0.0] * len(u)
    for t in range(len(u)):
        acc = xi[t]
        for i, ai in enumerate(a):
            if t - 1 - i >= 0:
                acc -= ai * y[t - 1 - i]
        for j, bj in enumerate(b):
            k = t - 1 - j - delay
            if k >= 0:
                acc += bj * u[k]
        y[t] = acc
    return np.asarray(y)


def filt(num, den, x):
    """``(num / den)(q^-1) x`` with ``num``, ``den`` in ascending powers of ``q^-1``."""
    num, den = np.asarray(num, float), np.asarray(den, float)
    num, den = num / den[0], den / den[0]
    x = np.asarray(x, float).tolist()
    y = [0.0] * len(x)
    nn, nd = num.tolist(), den.tolist()
    for t in range(len(x)):
        acc = 0.0
        for j, c in enumerate(nn):
            if t - j >= 0:
                acc += c * x[t - j]
        for i in range(1, len(nd)):
            if t - i >= 0:
                acc -= nd[i] * y[t - i]
        y[t] = acc
    return np.asarray(y)


def nominal_output(base, v, xi):
    return arx(play(v, base["c1"], base["c2"]), xi, base["a"], base["b"])


def _output_noise_gain(a, n=4000):
    """Standard deviation of ``xi / A`` for unit white ``xi``."""
    h = filt([1.0], np.r_[1.0, a], np.r_[1.0, np.zeros(n - 1)])
    return float(np.sqrt(np.sum(h ** 2)))


def spread(y):
    q5, q95 = np.quantile(y, [0.05, 0.95])
    return float(q95 - q5)


# ----------------------------------------------------------------------------- inputs
def make_input(rng, kind, n, amp):
    """One input record and its fundamental frequency (cycles/sample, ``None`` if none)."""
    t = np.arange(n)
    if kind == "plateaus":
        lengths = rng.integers(10, 80, size=n // 10 + 2)
        v = np.repeat(rng.uniform(-0.8, 0.8, size=len(lengths)), lengths)[:n] * amp
        f0 = 1.0 / rng.uniform(200, 800)
        v = v + 0.2 * amp * np.sin(2 * np.pi * f0 * t + rng.uniform(0, 2 * np.pi))
        return v, f0
    if kind == "multisine":
        period = int(rng.integers(100, 500))
        f0 = 1.0 / period
        ks = np.r_[1, rng.choice(np.arange(2, 16), size=rng.integers(3, 9), replace=False)]
        v = sum(np.cos(2 * np.pi * k * f0 * t + rng.uniform(0, 2 * np.pi)) / np.sqrt(k) for k in ks)
        return amp * v / np.max(np.abs(v)), f0
    if kind == "prbs":
        levels = np.array([-1.0, -0.4, 0.4, 1.0]) if rng.random() < 0.5 else np.array([-1.0, 1.0])
        hold = int(rng.integers(5, 40))
        steps = rng.choice(levels, size=n // hold + 2)
        return amp * np.repeat(steps, hold)[:n] * rng.uniform(0.8, 1.0), None
    if kind == "swept":
        f_lo, f_hi = rng.uniform(0.001, 0.005), rng.uniform(0.02, 0.08)
        phase = 2 * np.pi * (f_lo * t + (f_hi - f_lo) * t ** 2 / (2 * n))
        return amp * np.sin(phase + rng.uniform(0, 2 * np.pi)), f_lo
    if kind == "noise":
        r = rng.uniform(0.9, 0.99)
        w = filt([1 - r], [1.0, -r], rng.normal(size=n + 200))
        w = filt([1 - r], [1.0, -r], w)[200:]
        return amp * w / (3 * np.std(w)), None
    raise ValueError(f"input_kind must be one of {INPUT_KINDS}, got {kind!r}")


def _input_lines(v, frac=0.01):
    """Frequencies (cycles/sample) where the input periodogram is above ``frac`` of its peak."""
    spec = np.abs(np.fft.rfft(v - v.mean())) ** 2
    f = np.fft.rfftfreq(len(v))
    return f[spec > frac * spec.max()]


# ----------------------------------------------------------------------------- effects
def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def _bisect(fun, target, lo, hi, *, log=True, iters=14):
    """Knob in ``[lo, hi]`` where the increasing ``fun`` reaches ``target`` (or an end)."""
    if fun(hi) <= target:
        return hi
    if fun(lo) >= target:
        return lo
    for _ in range(iters):
        mid = math.sqrt(lo * hi) if log else 0.5 * (lo + hi)
        if fun(mid) < target:
            lo = mid
        else:
            hi = mid
    return math.sqrt(lo * hi) if log else 0.5 * (lo + hi)


def _perturbation(rng, base):
    """A random direction of parameter change: continuous-time poles, gains, band, curvature."""
    s = np.log(base["poles"].astype(complex))
    ds = rng.uniform(-0.5, 0.5, size=len(s))
    for i in range(len(s)):  # keep complex pairs conjugate
        if np.imag(s[i]) < 0:
            j = int(np.argmin(np.abs(s - np.conj(s[i]))))
            ds[i] = ds[j]
    db = rng.uniform(-0.4, 0.4, size=base["nb"])
    dw = rng.uniform(-0.5, 0.5) * base["slope"] * base["half"]
    dc = np.zeros(base["m"])
    dc[1] = rng.uniform(-0.3, 0.3) * base["slope"]
    return s, ds, db, dw, dc


def _perturbed(base, pert, lam):
    s, ds, db, dw, dc = pert
    new = dict(base)
    new["poles"] = np.exp(s * (1 + lam * ds))
    new["a"] = _poly_from_roots(new["poles"])
    new["b"] = base["b"] * (1 + lam * db)
    new["c1"] = base["c1"] + lam * dc - np.r_[lam * dw, np.zeros(base["m"] - 1)]
    new["c2"] = base["c2"] + lam * dc + np.r_[lam * dw, np.zeros(base["m"] - 1)]
    return new


class _Case:
    """Simulation state shared by the effect recipes of one case."""

    def __init__(self, rng, base, v, e, sigma_xi, f0):
        self.rng, self.base, self.v, self.e, self.sigma_xi, self.f0 = rng, base, v, e, sigma_xi, f0
        self.n = len(v)
        self.u = play(v, base["c1"], base["c2"])
        self.y_free = arx(self.u, np.zeros(self.n), base["a"], base["b"])
        self.y_lin = arx(self.u, sigma_xi * e, base["a"], base["b"])
        self.sigma_y = sigma_xi * _output_noise_gain(base["a"])

    def calibrate(self, simulate_free, target, lo, hi, **kw):
        return _bisect(lambda k: _rms(simulate_free(k) - self.y_free), target, lo, hi, **kw)


def _fx_parameter_mismatch(c, target):
    pert = _perturbation(c.rng, c.base)

    def sim(lam, xi=None):
        p = _perturbed(c.base, pert, lam)
        return nominal_output(p, c.v, np.zeros(c.n) if xi is None else xi)

    lam = c.calibrate(sim, target, 1e-4, 1.8)
    p = _perturbed(c.base, pert, lam)
    return sim(lam, c.sigma_xi * c.e), sim(lam), dict(a=p["a"], b=p["b"], c1=p["c1"], c2=p["c2"]), \
        "true parameters differ from the nominal ones (poles, gains, band)"


def _fx_output_saturation(c, target):
    sides = c.rng.choice(["upper", "lower", "both"])

    def levels(q):
        lo = np.quantile(c.y_free, q) if sides in ("lower", "both") else -np.inf
        hi = np.quantile(c.y_free, 1 - q) if sides in ("upper", "both") else np.inf
        return lo, hi

    q = c.calibrate(lambda q: np.clip(c.y_free, *levels(q)), target, 0.003, 0.35)
    lo, hi = levels(q)
    return np.clip(c.y_lin, lo, hi), np.clip(c.y_free, lo, hi), dict(lower=None if np.isinf(lo) else lo,
                                          upper=None if np.isinf(hi) else hi, fraction=q), \
        f"sensor range clips the measured output ({sides} side)"


def _fx_input_saturation(c, target):
    sides = c.rng.choice(["upper", "lower", "both"])

    def levels(q):
        lo = np.quantile(c.u, q) if sides in ("lower", "both") else -np.inf
        hi = np.quantile(c.u, 1 - q) if sides in ("upper", "both") else np.inf
        return lo, hi

    def sim(q, xi=None):
        return arx(np.clip(c.u, *levels(q)), np.zeros(c.n) if xi is None else xi,
                   c.base["a"], c.base["b"])

    q = c.calibrate(sim, target, 0.003, 0.4)
    lo, hi = levels(q)
    return sim(q, c.sigma_xi * c.e), sim(q), dict(lower=None if np.isinf(lo) else lo,
                                          upper=None if np.isinf(hi) else hi, fraction=q), \
        f"actuator limit on the backlash output ({sides} side)"


def _fx_extra_delay(c, target):
    d = int(c.rng.integers(1, 5))
    while d < 12 and _rms(arx(c.u, np.zeros(c.n), c.base["a"], c.base["b"], delay=d)
                          - c.y_free) < RATIO_MIN * c.sigma_y:
        d += 1
    y = arx(c.u, c.sigma_xi * c.e, c.base["a"], c.base["b"], delay=d)
    return y, arx(c.u, np.zeros(c.n), c.base["a"], c.base["b"], delay=d), dict(delay=d), f"transport delay of {d} more samples"


def _fx_unmodeled_dynamics(c, target):
    z = c.rng.uniform(-0.6, 0.6)

    def blocks(p):
        g = (1 - p) / (1 + z)
        return np.convolve(np.r_[1, c.base["a"]], [1, -p])[1:], g * np.convolve(c.base["b"], [1, z])

    def sim(p, xi=None):
        a, b = blocks(p)
        return arx(c.u, np.zeros(c.n) if xi is None else xi, a, b)

    p = c.calibrate(sim, target, 0.01, 0.97, log=False)
    a, b = blocks(p)
    return sim(p, c.sigma_xi * c.e), sim(p), dict(a=a, b=b, pole=p, zero=-z), \
        "an unmodelled first-order lag with a zero (sensor or actuator dynamics)"


def _fx_colored_noise(c, target, size):
    rho = 0.3 + 0.6 * size
    if c.rng.random() < 0.5:
        w = c.rng.uniform(0.2, 2.5)
        d = _poly_from_roots([rho * np.exp(1j * w), rho * np.exp(-1j * w)])
    else:
        d = _poly_from_roots([rho, c.rng.uniform(-0.3, 0.3) * rho])
    xi = filt([1.0], np.r_[1.0, d], c.e)
    gain = _output_noise_gain(np.convolve(np.r_[1, c.base["a"]], np.r_[1, d])[1:])
    xi = xi * c.sigma_y / (gain * np.std(c.e))
    return arx(c.u, xi, c.base["a"], c.base["b"]), c.y_free, dict(d=d, radius=rho, noise=xi), \
        "coloured (autoregressive) equation error"


def _fx_offset_drift(c, target):
    t = np.arange(c.n)
    if c.rng.random() < 0.5:
        shape, label = t / c.n, "linear sensor drift"
    else:
        tau = c.rng.uniform(0.3, 1.5) * c.n
        shape, label = 1 - np.exp(-t / tau), "thermal settling drift (exponential)"
    shape = (shape + c.rng.uniform(-0.3, 0.3)) * c.rng.choice([-1, 1])
    k = target / _rms(shape)
    return c.y_lin + k * shape, c.y_free + k * shape, dict(drift=k * shape[-1] - k * shape[0], shape=label), label


def _fx_parameter_change(c, target):
    tau = int(c.rng.uniform(0.2, 0.6) * c.n)
    pert = _perturbation(c.rng, c.base)

    def sim(lam, xi=None):
        xi = np.zeros(c.n) if xi is None else xi
        p = _perturbed(c.base, pert, lam)
        return _switched(c.v, xi, c.base, p, tau)

    lam = c.calibrate(sim, target, 1e-4, 1.8)
    p = _perturbed(c.base, pert, lam)
    return sim(lam, c.sigma_xi * c.e), sim(lam), dict(time=tau, a=p["a"], b=p["b"], c1=p["c1"],
                                            c2=p["c2"]), f"abrupt parameter change at sample {tau}"


def _switched(v, xi, before, after, tau):
    u = np.r_[play(v[:tau], before["c1"], before["c2"]), np.zeros(len(v) - tau)]
    u[tau:] = play(v[tau:], after["c1"], after["c2"], u0=u[tau - 1])
    y = [0.0] * len(v)
    for t in range(len(v)):
        a, b = (before["a"], before["b"]) if t < tau else (after["a"], after["b"])
        acc = xi[t]
        for i in range(len(a)):
            if t - 1 - i >= 0:
                acc -= a[i] * y[t - 1 - i]
        for j in range(len(b)):
            if t - 1 - j >= 0:
                acc += b[j] * u[t - 1 - j]
        y[t] = acc
    return np.asarray(y)


def _fx_periodic_disturbance(c, target):
    lines = _input_lines(c.v)
    for _ in range(200):
        f = c.rng.uniform(0.005, 0.45)
        if lines.size == 0 or np.min(np.abs(lines - f)) > 5.0 / c.n:
            break
    phase = c.rng.uniform(0, 2 * np.pi)
    amp = target * math.sqrt(2)
    line = amp * np.sin(2 * np.pi * f * np.arange(c.n) + phase)
    return c.y_lin + line, c.y_free + line, dict(frequency=f, amplitude=amp), f"mains/vibration line at {f:.4f} cycles/sample"


def _fx_output_nonlinearity(c, target):
    center, scale = np.median(c.y_free), 0.5 * spread(c.y_free)
    z_free = (c.y_free - center) / scale
    if c.rng.random() < 0.5:
        label = "compressive sensor (tanh)"
        g, alpha_max = (lambda z: np.tanh(z) - z), 0.9
    else:
        k2, k3 = c.rng.normal(size=2)
        k2, k3 = k2 / math.hypot(k2, k3), k3 / math.hypot(k2, k3)
        zmax = np.max(np.abs(z_free)) * 1.2
        slope_min = min(2 * k2 * zz + 3 * k3 * zz ** 2 for zz in np.linspace(-zmax, zmax, 101))
        label = "polynomial sensor curvature"
        g, alpha_max = (lambda z: k2 * z ** 2 + k3 * z ** 3), 0.8 / max(-slope_min, 1e-3)

    def sensor(y, alpha):
        return y + alpha * scale * g((y - center) / scale)

    alpha = c.calibrate(lambda al: sensor(c.y_free, al), target, 1e-5, alpha_max)
    return sensor(c.y_lin, alpha), sensor(c.y_free, alpha), dict(alpha=alpha, center=center, scale=scale), label


def _fx_coulomb_friction(c, target):
    eps = 0.02 * spread(c.y_free)
    viscous = 0.2 / max(np.std(c.y_free), 1e-12)
    u_max = float(np.max(np.abs(c.u)))

    def sim(force, xi=None):
        return _friction_loop(c.u, np.zeros(c.n) if xi is None else xi, c.base["a"],
                              c.base["b"], force, force * viscous, eps)

    force = c.calibrate(sim, target, 1e-4 * u_max, 0.8 * u_max)
    return sim(force, c.sigma_xi * c.e), sim(force), dict(force=force, viscous=force * viscous, width=eps), \
        "dry + viscous friction opposing the motion of the driven side, inside the dynamics"


def _friction_loop(u, xi, a, b, fc, cv, eps):
    """Force ``u`` in, velocity ``y`` out; friction ``fc sat(y/eps) + cv y`` opposes ``u``."""
    u, xi = np.asarray(u).tolist(), np.asarray(xi).tolist()
    y, net = [0.0] * len(u), [0.0] * len(u)
    for t in range(len(u)):
        acc = xi[t]
        for i in range(len(a)):
            if t - 1 - i >= 0:
                acc -= a[i] * y[t - 1 - i]
        for j in range(len(b)):
            if t - 1 - j >= 0:
                acc += b[j] * net[t - 1 - j]
        y[t] = acc
        net[t] = u[t] - fc * min(max(acc / eps, -1.0), 1.0) - cv * acc
    return np.asarray(y)


def _fx_branch_degree(c, target):
    m, amp = c.base["m"], c.base["amp"]
    sign = c.rng.choice([-1.0, 1.0])
    rel = 1 + c.rng.uniform(-0.2, 0.2)
    grid = np.linspace(-1.3 * amp, 1.3 * amp, 201)

    def branches(k):
        e = np.zeros(m + 1)
        e[m] = sign * k * c.base["slope"] / amp ** (m - 1)
        c1 = np.r_[c.base["c1"], 0.0] + e
        c2 = np.r_[c.base["c2"], 0.0] + e * rel
        return c1, c2

    k_max = 1.0
    while k_max > 1e-4 and not _branches_ok(*branches(k_max), grid, c.base["slope"] * 0.5,
                                            c.base["half"] * 0.5):
        k_max *= 0.8
    k = c.calibrate(lambda k: arx(play(c.v, *branches(k)), np.zeros(c.n), c.base["a"],
                                  c.base["b"]), target, 1e-5, k_max)
    c1, c2 = branches(k)
    u = play(c.v, c1, c2)
    return arx(u, c.sigma_xi * c.e, c.base["a"], c.base["b"]), \
        arx(u, np.zeros(c.n), c.base["a"], c.base["b"]), dict(c1=c1, c2=c2), f"branches of degree {m} (spring stiffening), one above the model"


def _fx_level_dependent_dynamics(c, target):
    """Torricelli tank: local time constant and gain both scale with sqrt(level)."""
    ymin, ybar, sp = np.min(c.y_free), np.mean(c.y_free), max(spread(c.y_free), 1e-12)
    s = np.log(c.base["poles"].astype(complex))
    rhos = np.exp(np.linspace(np.log(0.1), np.log(10.0), 400))
    a_grid = np.stack([_poly_from_roots(np.exp(s / r)) for r in rhos])
    scale_grid = rhos * (1 + a_grid.sum(1)) / (1 + c.base["a"].sum())

    def sim(kappa, xi=None):
        h_base = sp / kappa
        return _tank_loop(c.u, np.zeros(c.n) if xi is None else xi, a_grid, scale_grid, rhos,
                          c.base["b"], ymin - h_base, h_base + ybar - ymin)

    kappa = c.calibrate(sim, target, 1e-3, 20.0)
    return sim(kappa, c.sigma_xi * c.e), sim(kappa), dict(level_ratio=kappa), \
        "tank with Torricelli outflow: gain and time constant grow with sqrt(level)"


def _tank_loop(u, xi, a_grid, scale_grid, rhos, b, bottom, h_ref):
    log_r0, dlog = math.log(rhos[0]), math.log(rhos[1] / rhos[0])
    u, xi = np.asarray(u).tolist(), np.asarray(xi).tolist()
    a_grid, scale_grid, b = a_grid.tolist(), scale_grid.tolist(), list(b)
    y = [0.0] * len(u)
    prev = 0.0
    for t in range(len(u)):
        level = max(prev - bottom, 1e-3 * h_ref)
        k = int(round((0.5 * math.log(level / h_ref) - log_r0) / dlog))
        k = min(max(k, 0), len(a_grid) - 1)
        a, g = a_grid[k], scale_grid[k]
        acc = xi[t]
        for i in range(len(a)):
            if t - 1 - i >= 0:
                acc -= a[i] * y[t - 1 - i]
        for j in range(len(b)):
            if t - 1 - j >= 0:
                acc += g * b[j] * u[t - 1 - j]
        y[t] = prev = acc
    return np.asarray(y)


def _fx_harmonic_distortion(c, target):
    """A static input-driven harmonic generator: ``T_k`` of the normalised input (for a
    sinusoidal input exactly a line at ``k`` times its frequency)."""
    k = int(c.rng.choice([2, 3]))
    lo, hi = np.min(c.v), np.max(c.v)
    vn = (2 * c.v - (lo + hi)) / max(hi - lo, 1e-12)
    line = np.cos(k * np.arccos(np.clip(vn, -1, 1)))
    line = line - line.mean()
    if _rms(line) < 1e-9 * max(_rms(vn), 1e-300):
        raise ValueError(f"harmonic_distortion: a harmonic of order {k} of this input is constant")
    gain = target / _rms(line)
    f = None if c.f0 is None else k * c.f0
    return c.y_lin + gain * line, c.y_free + gain * line, dict(order=k, amplitude=gain, frequency=f), \
        f"input-driven harmonic of order {k} (e.g. a force proportional to current^{k})"


def _fx_missing_input(c, target):
    kind = c.rng.choice(INPUT_KINDS)
    w, _ = make_input(c.rng, kind, c.n, 1.0)
    bw = c.rng.normal(size=int(c.rng.integers(1, 4)))
    y_w = arx(w, np.zeros(c.n), c.base["a"], bw)
    g = target / max(_rms(y_w), 1e-12)
    return c.y_lin + g * y_w, c.y_free + g * y_w, dict(b_aux=g * bw, aux_kind=str(kind), channel=w), \
        f"a second recorded input ({kind}) drives the output through the same dynamics"


_RECIPES = {name: globals()[f"_fx_{name}"] for name in ALL_EFFECTS}


# ----------------------------------------------------------------------------- entry point
def concealed_case(rng, effect, *, input_kind=None, n=None, base=None, nominal="true"):
    """One recording of a random HB-Hammerstein system with one concealed effect (or none).

    **Arguments:**

    - `rng`: a ``numpy.random.Generator``.
    - `effect`: a name from :data:`ALL_EFFECTS`, or ``None`` for a clean recording.
    - `input_kind`: one of :data:`INPUT_KINDS` (random if ``None``).
    - `n`: record length (random in 1000-8000, multiples of 500, if ``None``).
    - `base`: a dict from :func:`random_base` (random if ``None``).
    - `nominal`: ``"true"`` (the base system itself, as the package's own suite does) or
      ``"fitted"`` (``hbjax.fit`` on a separate clean recording of the base system).

    **Returns:** a dict with ``v``, ``y``, ``nominal_model`` (an :class:`hbjax.Hammerstein`),
    ``effect``, ``size`` (0 just detectable .. 1 strong), ``channels`` (name -> array, only
    for ``missing_input``, else ``{}``), ``description``, and for checks: ``noise`` (the
    equation error ``xi`` actually used), ``y_free`` (output without noise, effect
    included; for ``colored_noise`` the nominal one), ``y_nominal_free``, ``sigma_y``
    (output noise std), ``ratio`` (RMS effect / ``sigma_y``), ``truth``, ``base``,
    ``input_kind``, ``f0``.
    """
    if effect is not None and effect not in _RECIPES:
        raise ValueError(f"effect must be None or one of {ALL_EFFECTS}, got {effect!r}")
    for _ in range(20):  # redraw the rare system whose knob range cannot reach RATIO_MIN
        case = _draw(rng, effect, input_kind, n, base, nominal)
        if case["effect"] in (None, "colored_noise") or case["ratio"] >= RATIO_MIN * 0.95:
            return case
    raise RuntimeError(f"{effect}: no detectable case in 20 draws")


def _draw(rng, effect, input_kind, n, base, nominal):
    base = random_base(rng) if base is None else base
    n = int(500 * rng.integers(N_MIN // 500, N_MAX // 500 + 1)) if n is None else int(n)
    # A harmonic of the input's fundamental needs an input that has one.
    kinds = ("plateaus", "multisine", "swept") if effect == "harmonic_distortion" else INPUT_KINDS
    kind = str(rng.choice(kinds)) if input_kind is None else input_kind
    v, f0 = make_input(rng, kind, n, base["amp"])
    y_nom_free = nominal_output(base, v, np.zeros(n))
    noise_fraction = float(np.exp(rng.uniform(np.log(NOISE_MIN), np.log(NOISE_MAX))))
    sigma_y = noise_fraction * spread(y_nom_free)
    e = rng.standard_normal(n)
    sigma_xi = sigma_y / _output_noise_gain(base["a"])
    case = _Case(rng, base, v, e, sigma_xi, f0)
    size = float(rng.uniform())
    ratio = float(np.exp(np.log(RATIO_MIN) + size * np.log(RATIO_MAX / RATIO_MIN)))
    channels, truth = {}, {}
    xi = sigma_xi * e
    if effect is None:
        y, y_free, description = case.y_lin, y_nom_free, "clean: nominal model + white equation error"
    elif effect == "colored_noise":
        y, y_free, truth, description = _fx_colored_noise(case, ratio * sigma_y, size)
        xi = truth.pop("noise")
    else:
        y, y_free, truth, description = _RECIPES[effect](case, ratio * sigma_y)
        if effect == "missing_input":
            channels = {"aux": truth.pop("channel")}
    measured = _rms(y_free - y_nom_free) / sigma_y if effect != "colored_noise" else ratio
    if effect not in (None, "colored_noise"):  # the size actually reached (knob ranges are capped)
        size = float(np.clip(np.log(max(measured, 1e-12) / RATIO_MIN) / np.log(RATIO_MAX / RATIO_MIN), 0, 1))
    if not np.all(np.isfinite(y)):
        raise FloatingPointError(f"{effect}: non-finite output")
    return dict(v=v, y=y, nominal_model=_nominal(base, v, rng, nominal, kind), effect=effect,
                size=size if effect is not None else 0.0, channels=channels,
                description=description, noise=xi, y_free=y_free, y_nominal_free=y_nom_free,
                sigma_y=sigma_y, noise_fraction=noise_fraction, ratio=measured, truth=truth,
                base=base, input_kind=kind, f0=f0)


def _nominal(base, v, rng, mode, kind):
    import hbjax

    if mode == "true":
        return hammerstein(base)
    if mode != "fitted":
        raise ValueError(f"nominal must be 'true' or 'fitted', got {mode!r}")
    import jax

    v_id, _ = make_input(rng, kind, len(v), base["amp"])
    y_id = nominal_output(base, v_id, 0.01 * spread(v_id) * rng.standard_normal(len(v)))
    res = hbjax.fit((v_id, y_id), na=base["na"], nb=base["nb"], m=base["m"],
                    key=jax.random.PRNGKey(int(rng.integers(2 ** 31))))
    return res.model
