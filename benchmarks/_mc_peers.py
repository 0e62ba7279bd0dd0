"""Peer implementations of the Monte Carlo study for benchmarks/monte_carlo.py: the same
algorithm as hbjax.monte_carlo with estimator="giri" (simulate the three experiments with
white equation error, then hbjax._identify.giri.estimate_giri's steps, diagnostics and result codes
included), in plain NumPy (a loop over realisations) and in Numba (prange over realisations).
"""

import numba
import numpy as np


# ----------------------------------------------------------------------------- shared setup
def setup(model, design, T):
    """Everything that does not depend on the noise: inputs, known u~ of v2, plateau instants."""
    return dict(
        c1=np.asarray(model.backlash.c1), c2=np.asarray(model.backlash.c2),
        a=np.asarray(model.arx.a), b=np.asarray(model.arx.b),
        v=np.stack([design.constant_input(T), design.binary_input(T), design.staircase_input(T)]),
        u2=design.binary_internal(T),
        t_inst=design.estimation_instants(T)[0], j_inst=design.estimation_instants(T)[1],
        levels=design.staircase_levels(), n=design.n, m=design.m, h_m=design.h_m,
    )


_COND_LIMIT, _GAP_TOL = 1e12, 0.5


# ------------------------------------------------------------------------------- plain NumPy
def numpy_simulate(c1, c2, a, b, v, xi):
    """Play operator + ARX recursion, one Python loop over time (a user's NumPy simulator)."""
    T = v.shape[0]
    y = np.zeros(T)
    u = np.zeros(T)
    state = 0.0
    na, nb = len(a), len(b)
    for t in range(T):
        p1 = np.polynomial.polynomial.polyval(v[t], c1)
        p2 = np.polynomial.polynomial.polyval(v[t], c2)
        state = min(max(state, min(p1, p2)), max(p1, p2))
        u[t] = state
        acc = xi[t]
        for i in range(na):
            if t - 1 - i >= 0:
                acc -= a[i] * y[t - 1 - i]
        for i in range(nb):
            if t - 1 - i >= 0:
                acc += b[i] * u[t - 1 - i]
        y[t] = acc
    return y


def _lag(x, k):
    return np.concatenate([np.zeros(k), x[:-k]]) if k else x


def _np_offset(y1, transient):
    return y1[max(int(transient), 1):].mean()


def _np_ls(n, y2, u2, offset):
    yt = y2 - offset
    phi = np.stack([-_lag(yt, i) for i in range(1, n + 1)] + [_lag(u2, i) for i in range(1, n + 1)], 1)[n:]
    target = yt[n:]
    rows = phi.shape[0]
    gram = phi.T @ phi / rows
    scale = np.sqrt(np.diag(gram))
    scale = np.where(scale > 0, scale, 1.0)
    gram_s = gram / np.outer(scale, scale)
    theta = np.linalg.solve(gram_s, (phi.T @ target / rows) / scale) / scale
    eig = np.linalg.eigvalsh(gram_s)
    cond = eig[-1] / max(eig[0], 1e-300)
    resid = target - phi @ theta
    var = np.sum(resid**2) / max(rows - 2 * n, 1)
    cov = var * np.linalg.inv(gram_s) / np.outer(scale, scale) / rows
    return theta[:n], theta[n:], cond, np.sqrt(max(np.sum(cov[n:, n:]), 0.0))


def _np_transient(a, limit):
    n = len(a)
    comp = np.zeros((n, n))
    comp[0] = -a
    comp[1:, :-1] = np.eye(n - 1)
    k, done = 1, False
    for _ in range(40):
        settled = np.linalg.norm(comp) < 1e-10
        if not (done or settled):
            k *= 2
        done = done or settled
        comp = comp @ comp
    return min(k, limit)


def _np_vander(levels, values, h_m):
    p = np.arange(len(levels))
    vs = (levels[:, None] / h_m) ** p
    coef = np.linalg.lstsq(vs, values, rcond=None)[0]
    s = np.linalg.svd(vs, compute_uv=False)
    return coef / h_m**p, s[0] / s[-1]


def numpy_estimate(s, y1, y2, y3):
    """The steps of hbjax._identify.giri.estimate_giri in NumPy; returns (theta, code)."""
    n, m, h_m = s["n"], s["m"], s["h_m"]
    half = len(y1) // 2
    a0 = _np_ls(n, y2, s["u2"], _np_offset(y1, half))[0]
    offset = _np_offset(y1, _np_transient(a0, half))
    a, b_star, cond_ls, b_std = _np_ls(n, y2, s["u2"], offset)
    bsum = b_star.sum()
    z = y3.copy()
    for i in range(n):
        z += a[i] * _lag(y3, i + 1)
    zi = z[s["t_inst"]]
    zbar = np.array([zi[s["j_inst"] == j].mean() for j in range(2 * m)]) / bsum
    c1, k1 = _np_vander(s["levels"][:m], zbar[:m], h_m)
    c2, k2 = _np_vander(s["levels"][m:], zbar[m:], h_m)
    theta = np.concatenate([a, b_star, c1, c2])
    gap = zbar[m] - zbar[0]
    code = _code(np.isfinite(y1).all() and np.isfinite(y2).all() and np.isfinite(y3).all(),
                 cond_ls, bsum, b_std, np.abs(b_star).sum(), np.isfinite(theta).all(),
                 max(k1, k2), gap)
    return theta, code


def _code(finite, cond_ls, bsum, b_std, babs, theta_finite, cond_v, gap):
    if not finite:
        return 1
    if not cond_ls < _COND_LIMIT:
        return 2
    if abs(bsum) <= 4 * b_std + 1e-8 * babs:
        return 3
    if not theta_finite or not cond_v < _COND_LIMIT:
        return 5
    if not abs(gap - 1.0) <= _GAP_TOL:
        return 4
    return 0


def numpy_study(s, realisations, noise_std, seed):
    """Loop over realisations: draw noise, simulate the three experiments, estimate."""
    T = s["v"].shape[1]
    rng = np.random.default_rng(seed)
    out = np.empty((realisations, s["n"] * 2 + 2 * s["m"]))
    codes = np.empty(realisations, np.int64)
    for r in range(realisations):
        xi = noise_std * rng.standard_normal((3, T))
        y = [numpy_simulate(s["c1"], s["c2"], s["a"], s["b"], s["v"][e], xi[e]) for e in range(3)]
        out[r], codes[r] = numpy_estimate(s, *y)
    return out, codes


# ------------------------------------------------------------------------------------ Numba
@numba.njit(cache=True, fastmath=False)
def _nb_simulate(c1, c2, a, b, v, xi, y):
    T = v.shape[0]
    na, nb, m = a.shape[0], b.shape[0], c1.shape[0]
    ulag = np.zeros(nb)
    state = 0.0
    for t in range(T):
        acc = xi[t]
        for i in range(na):
            if t - 1 - i >= 0:
                acc -= a[i] * y[t - 1 - i]
        for i in range(nb):
            acc += b[i] * ulag[i]
        y[t] = acc
        p1 = c1[m - 1]
        p2 = c2[m - 1]
        for k in range(m - 2, -1, -1):
            p1 = p1 * v[t] + c1[k]
            p2 = p2 * v[t] + c2[k]
        state = min(max(state, min(p1, p2)), max(p1, p2))
        for i in range(nb - 1, 0, -1):
            ulag[i] = ulag[i - 1]
        ulag[0] = state


@numba.njit(cache=True)
def _nb_offset(y1, transient):
    start = max(transient, 1)
    acc = 0.0
    for t in range(start, y1.shape[0]):
        acc += y1[t]
    return acc / (y1.shape[0] - start)


@numba.njit(cache=True)
def _nb_ls(n, y2, u2, offset):
    """Normal equations of (26) accumulated in one pass (no regressor matrix)."""
    T = y2.shape[0]
    p = 2 * n
    gram = np.zeros((p, p))
    rhs = np.zeros(p)
    phi = np.zeros(p)
    yy = 0.0
    for t in range(n, T):
        for i in range(n):
            phi[i] = -(y2[t - 1 - i] - offset)
            phi[n + i] = u2[t - 1 - i]
        target = y2[t] - offset
        yy += target * target
        for i in range(p):
            rhs[i] += phi[i] * target
            for j in range(i, p):
                gram[i, j] += phi[i] * phi[j]
    rows = T - n
    for i in range(p):
        for j in range(i):
            gram[i, j] = gram[j, i]
    gram /= rows
    rhs /= rows
    scale = np.sqrt(np.diag(gram).copy())
    for i in range(p):
        if not scale[i] > 0:
            scale[i] = 1.0
    gram_s = gram / np.outer(scale, scale)
    theta = np.linalg.solve(gram_s, rhs / scale) / scale
    eig = np.linalg.eigvalsh(gram_s)
    cond = eig[-1] / max(eig[0], 1e-300)
    # sum of squared residuals from the normal equations: |t|^2 - 2 theta.rhs + theta' G theta
    ssr = yy - 2 * rows * np.dot(theta, rhs) + rows * np.dot(theta, gram @ theta)
    var = ssr / max(rows - 2 * n, 1)
    cov = var * np.linalg.inv(gram_s) / np.outer(scale, scale) / rows
    return theta[:n].copy(), theta[n:].copy(), cond, np.sqrt(max(np.sum(cov[n:, n:]), 0.0))


@numba.njit(cache=True)
def _nb_transient(a, limit):
    n = a.shape[0]
    comp = np.zeros((n, n))
    comp[0] = -a
    for i in range(1, n):
        comp[i, i - 1] = 1.0
    k, done = 1, False
    for _ in range(40):
        settled = np.sqrt(np.sum(comp * comp)) < 1e-10
        if not (done or settled):
            k *= 2
        done = done or settled
        comp = comp @ comp
    return min(k, limit)


@numba.njit(cache=True)
def _nb_vander(levels, values, h_m):
    m = levels.shape[0]
    vs = np.empty((m, m))
    for i in range(m):
        for k in range(m):
            vs[i, k] = (levels[i] / h_m) ** k
    coef = np.linalg.lstsq(vs, values)[0]
    s = np.linalg.svd(vs)[1]
    for k in range(m):
        coef[k] /= h_m**k
    return coef, s[0] / s[-1]


@numba.njit(cache=True)
def _nb_estimate(n, m, h_m, y1, y2, y3, u2, t_inst, j_inst, levels, out):
    T = y1.shape[0]
    half = T // 2
    a0 = _nb_ls(n, y2, u2, _nb_offset(y1, half))[0]
    offset = _nb_offset(y1, _nb_transient(a0, half))
    a, b_star, cond_ls, b_std = _nb_ls(n, y2, u2, offset)
    bsum = b_star.sum()
    zsum = np.zeros(2 * m)
    cnt = np.zeros(2 * m)
    for k in range(t_inst.shape[0]):
        t = t_inst[k]
        z = y3[t]
        for i in range(n):
            if t - 1 - i >= 0:
                z += a[i] * y3[t - 1 - i]
        zsum[j_inst[k]] += z
        cnt[j_inst[k]] += 1.0
    zbar = zsum / cnt / bsum
    c1, k1 = _nb_vander(levels[:m].copy(), zbar[:m].copy(), h_m)
    c2, k2 = _nb_vander(levels[m:].copy(), zbar[m:].copy(), h_m)
    out[:n] = a
    out[n:2 * n] = b_star
    out[2 * n:2 * n + m] = c1
    out[2 * n + m:] = c2
    finite = np.all(np.isfinite(y1)) and np.all(np.isfinite(y2)) and np.all(np.isfinite(y3))
    gap = zbar[m] - zbar[0]
    if not finite:
        return 1
    if not cond_ls < _COND_LIMIT:
        return 2
    if abs(bsum) <= 4 * b_std + 1e-8 * np.abs(b_star).sum():
        return 3
    if not np.all(np.isfinite(out)) or not max(k1, k2) < _COND_LIMIT:
        return 5
    if not abs(gap - 1.0) <= _GAP_TOL:
        return 4
    return 0


@numba.njit(parallel=True, cache=True)
def numba_study(c1, c2, a, b, v, u2, t_inst, j_inst, levels, n, m, h_m,
                realisations, noise_std, seed):
    """prange over realisations; each draws its noise (thread-local generator seeded per
    realisation, so the result does not depend on the thread count), simulates, estimates."""
    T = v.shape[1]
    p = 2 * n + 2 * m
    out = np.empty((realisations, p))
    codes = np.empty(realisations, np.int64)
    for r in numba.prange(realisations):
        np.random.seed(seed + r)
        y = np.empty((3, T))
        xi = np.empty(T)
        for e in range(3):
            for t in range(T):
                xi[t] = noise_std * np.random.standard_normal()
            _nb_simulate(c1, c2, a, b, v[e], xi, y[e])
        codes[r] = _nb_estimate(n, m, h_m, y[0], y[1], y[2], u2, t_inst, j_inst, levels, out[r])
    return out, codes


@numba.njit(cache=True)
def numba_one(c1, c2, a, b, v, u2, t_inst, j_inst, levels, n, m, h_m, xi):
    """One realisation from given noise records (3, T): for the agreement check."""
    T = v.shape[1]
    y = np.empty((3, T))
    for e in range(3):
        _nb_simulate(c1, c2, a, b, v[e], xi[e], y[e])
    out = np.empty(2 * n + 2 * m)
    code = _nb_estimate(n, m, h_m, y[0], y[1], y[2], u2, t_inst, j_inst, levels, out)
    return out, code
