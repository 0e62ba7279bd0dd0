"""Residual analysis of a nominal model (NumPy; run once per diagnosis).

The classical validation tests (MATLAB ``resid``): whiteness of the prediction error
(autocorrelation with a 99% band, Ljung-Box), independence from past inputs
(cross-correlation), plus what the diagnosis needs to *locate* a mismatch: dependence of
the residual on regime variables (input level, output level, motion direction), its
spectral peak, and windows in time where the residual is large.
"""

from __future__ import annotations

import math

import numpy as np

from .._misc import as_float_array, check_finite, chi2_sf, no_spread, same_length

Z99 = 2.5758293035489004  # two-sided 99% normal quantile


def correlation(x: np.ndarray, z: np.ndarray, lags: int) -> np.ndarray:
    """``r(k) = sum_t x(t) z(t-k) / (||x|| ||z||)`` for ``k = 0..lags``."""
    x = x - x.mean()
    z = z - z.mean()
    # Scale-free: each record divided by its largest magnitude first, so that the sums of
    # squares (and their product) neither overflow nor underflow whatever the data's units.
    x = x / (np.max(np.abs(x), initial=0.0) or 1.0)
    z = z / (np.max(np.abs(z), initial=0.0) or 1.0)
    den = np.sqrt(np.sum(x * x)) * np.sqrt(np.sum(z * z)) or 1.0
    return np.array([np.sum(x[k:] * z[:len(z) - k]) / den for k in range(lags + 1)])


def whiteness(eps: np.ndarray, lags: int = 25) -> dict:
    """Autocorrelation of ``eps`` at lags 1..``lags`` against the 99% band, and Ljung-Box."""
    n = len(eps)
    r = correlation(eps, eps, lags)[1:]
    q = n * (n + 2) * np.sum(r**2 / (n - np.arange(1, lags + 1)))
    return {"max_abs_acf": float(np.max(np.abs(r))), "band99": Z99 / math.sqrt(n),
            "lags_outside": int(np.sum(np.abs(r) > Z99 / math.sqrt(n))),
            "ljung_box": float(q), "p_value": float(chi2_sf(q, lags))}


def lagged_gram(z: np.ndarray, lags: int) -> np.ndarray:
    """``G[j, k] = sum_t z(t - j) z(t - k)`` over the samples where both lags are recorded
    (``z`` zero before its start, as :func:`correlation` sums): the covariance, up to the
    residual variance, of the sums ``sum_t e(t) z(t - k)`` of white residuals ``e``."""
    # (for k = j + d: the sum of z(s) z(s - d) over d <= s < n - j, from one cumulative
    # sum per d, without the (n, lags + 1) matrix of windows)
    n = z.shape[0]
    gram = np.zeros((lags + 1, lags + 1))
    for d in range(min(lags, n - 1) + 1):
        c = np.concatenate([[0.0], np.cumsum(z[d:] * z[:n - d])])  # c[i]: s < d + i
        for j in range(lags + 1 - d):
            gram[j, j + d] = gram[j + d, j] = c[max(n - j - d, 0)]
    return gram


def coloured_input_statistic(r: np.ndarray, u: np.ndarray, lags: int) -> tuple[float, int]:
    """``(N r^T R_u^+ r, rank R_u)`` for the cross-correlations ``r`` of white residuals
    with ``u(t-k)``, ``k = 0..lags`` (:func:`correlation`): under the null hypothesis
    ``r ~ N(0, R_u / N)``, ``R_u`` the Gram matrix of the input's lagged windows over its
    sum of squares (:func:`lagged_gram`), so the statistic is chi-square with ``rank R_u``
    degrees of freedom whatever the input's colour. (``N sum r^2`` against ``chi2(lags +
    1)`` holds for a white input only: with a step input held 25 samples it rejected a
    correct model at p < 1e-3 in 9.5 % of white residual draws. The Toeplitz matrix of the
    input's autocorrelation stands for the Gram matrix only where it is well conditioned:
    for a multisine of 5 lines, whose Gram matrix has 10 large eigenvalues and the rest
    from the record's ends, it made the test reject a true model at 5 % in 0 of 200
    records, mean p-value 0.84.)"""
    z = np.asarray(u, float) - np.mean(u)
    z = z / (np.max(np.abs(z), initial=0.0) or 1.0)
    R = lagged_gram(z, lags) / (float(np.sum(z * z)) or 1.0)
    w, U = np.linalg.eigh(R)
    keep = w > 1e-8 * w.max()
    z = U[:, keep].T @ r
    return float(u.shape[0] * np.sum(z**2 / w[keep])), int(np.sum(keep))


def independence(eps: np.ndarray, u: np.ndarray, lags: int = 25) -> dict:
    """Cross-correlation of ``eps`` with past inputs ``u(t-k)``, ``k = 0..lags``, against
    the 99% band, and its chi-square test for a coloured input
    (:func:`coloured_input_statistic`, as :func:`hbjax.resid`)."""
    n = len(eps)
    r = correlation(eps, u, lags)
    stat, dof = coloured_input_statistic(r, np.asarray(u, float), lags)
    return {"max_abs_ccf": float(np.max(np.abs(r))), "band99": Z99 / math.sqrt(n),
            "lags_outside": int(np.sum(np.abs(r) > Z99 / math.sqrt(n))),
            "statistic": stat, "p_value": float(chi2_sf(stat, dof)) if dof else 1.0}


def regime_dependence(res: np.ndarray, regime: np.ndarray, bins: int = 8) -> dict:
    """How much of the residual's variance its mean per regime bin explains (an F-type
    ratio). ``regime`` is binned by quantiles; a sign variable gives at most 3 bins."""
    edges = np.unique(np.quantile(regime, np.linspace(0, 1, bins + 1)))
    idx = np.clip(np.searchsorted(edges, regime, side="right") - 1, 0, max(len(edges) - 2, 0))
    groups = [res[idx == g] for g in np.unique(idx)]
    means = np.array([g.mean() for g in groups])
    counts = np.array([len(g) for g in groups])
    between = float(np.sum(counts * (means - res.mean()) ** 2))
    total = float(np.sum((res - res.mean()) ** 2)) or 1.0
    worst = int(np.argmax(np.abs(means - res.mean()) * np.sqrt(counts)))
    lo = float(edges[min(worst, len(edges) - 1)])
    hi = float(edges[min(worst + 1, len(edges) - 1)])
    return {"explained": between / total, "worst_range": [lo, hi],
            "worst_mean": float(means[worst]), "bins": len(groups)}


def spectral_peaks(res: np.ndarray, count: int = 3, pad: int = 4,
                   exclude: np.ndarray | None = None) -> list[tuple[float, float]]:
    """The ``count`` strongest periodogram peaks ``(frequency in cycles/sample, peak to
    median power ratio)``; bins where ``exclude`` (a periodogram of the input on the same
    grid) is strong are skipped: a disturbance "unrelated to the input"."""
    n = len(res)
    nfft = int(2 ** math.ceil(math.log2(n * pad)))
    p = np.abs(np.fft.rfft((res - res.mean()) * np.hanning(n), nfft)) ** 2
    f = np.fft.rfftfreq(nfft)
    ok = f > 3.0 / n
    if exclude is not None:
        ok &= exclude < 0.05 * exclude.max()
    med = float(np.median(p[ok])) if np.any(ok) else 1.0
    peaks = []
    pw = np.where(ok, p, 0.0)
    width = max(1, int(2 * nfft / n))
    for _ in range(count):
        k = int(np.argmax(pw))
        if pw[k] <= 0:
            break
        peaks.append((float(f[k]), float(pw[k] / (med or 1.0))))
        pw[max(0, k - width):k + width + 1] = 0.0
    return peaks


def periodogram(x: np.ndarray, pad: int = 4) -> np.ndarray:
    n = len(x)
    nfft = int(2 ** math.ceil(math.log2(n * pad)))
    return np.abs(np.fft.rfft((x - x.mean()) * np.hanning(n), nfft)) ** 2


def windows(mask: np.ndarray, min_gap: int = 10, min_len: int = 3, offset: int = 0,
            limit: int = 8) -> list[list[int]]:
    """Runs of ``True`` in ``mask`` as ``[start, stop)`` sample windows; runs closer than
    ``min_gap`` are merged, shorter than ``min_len`` dropped, the ``limit`` longest kept
    (in time order)."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return []
    runs, start, prev = [], idx[0], idx[0]
    for i in idx[1:]:
        if i - prev > min_gap:
            runs.append([int(start) + offset, int(prev) + 1 + offset])
            start = i
        prev = i
    runs.append([int(start) + offset, int(prev) + 1 + offset])
    runs = [r for r in runs if r[1] - r[0] >= min_len]
    runs = sorted(sorted(runs, key=lambda r: r[0] - r[1])[:limit])
    return runs


def diebold_mariano(ref: np.ndarray, new: np.ndarray) -> float:
    """z statistic that ``new`` has smaller squared error than ``ref`` (paired, with a
    Newey-West long-run variance: residuals of a dynamic model are autocorrelated)."""
    # The z statistic is scale-free: residuals in units of their largest magnitude, so that
    # squares and products of squares stay in float range for any data scale.
    scale = max(np.max(np.abs(ref), initial=0.0), np.max(np.abs(new), initial=0.0)) or 1.0
    ref, new = ref / scale, new / scale
    d = ref**2 - new**2
    n = len(d)
    lag = max(1, math.ceil(4 * (n / 100) ** (2 / 9)))  # Newey-West rule of thumb
    dc = d - d.mean()
    lrv = np.sum(dc * dc) / n
    for k in range(1, min(lag, n - 1) + 1):
        lrv += 2 * (1 - k / (lag + 1)) * np.sum(dc[k:] * dc[:-k]) / n
    if lrv <= 0:
        return 0.0 if d.mean() == 0 else math.copysign(np.inf, d.mean())
    return float(d.mean() / math.sqrt(lrv / n))


def event_sign_test(ref: np.ndarray, new: np.ndarray, changed: np.ndarray,
                    gap: int = 5) -> dict:
    """Exact one-sided sign test that ``new`` errors are smaller than ``ref`` errors over
    *events*: the samples where ``changed`` is true, grouped into runs at most ``gap``
    samples apart, each scored by the sign of its summed squared-error difference.

    For an effect that acts in a few bursts (a clip the output reaches a handful of
    times), the Diebold-Mariano statistic rests on a long-run variance estimated from a
    few dozen samples, where its normal approximation does not hold; the events are
    closer to independent than the samples within one, and the binomial tail is exact.
    Returns ``{"events", "better", "p"}`` (``p``: probability of at least ``better`` of
    ``events`` under no difference)."""
    d = np.asarray(ref, float) ** 2 - np.asarray(new, float) ** 2
    changed = np.asarray(changed, bool)
    groups = windows(changed, min_gap=gap, min_len=1, limit=len(d))
    scores = [float(np.sum(d[a:b][changed[a:b]])) for a, b in groups]
    events, better = len(scores), sum(1 for x in scores if x > 0)
    p = sum(math.comb(events, k) for k in range(better, events + 1)) / 2.0 ** events
    return {"events": events, "better": better, "p": float(p)}


def fit_percent(y, y_hat) -> float:
    """``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` (MATLAB ``compare``'s NRMSE fit).

    **Arguments:**

    - `y`: the measured output, a 1-D array-like of finite samples that is not constant.
    - `y_hat`: the model's output (simulated or predicted), finite, as long as `y`.

    **Returns:** the fit in percent: 100 for a perfect match, 0 for no better than the mean
    of `y`, negative for worse. ``ValueError`` for a constant `y` (no spread, up to
    rounding): the fit is relative to that spread and so undefined.
    """
    y = as_float_array(y, "y", ndim=1, host=True)
    y_hat = as_float_array(y_hat, "y_hat", ndim=1, host=True)
    if y.shape[0] == 0:
        raise ValueError("`y` must hold at least one sample, got an empty array.")
    same_length(y=y, y_hat=y_hat)
    eps = np.finfo(y.dtype).eps  # the rounding of the data as given (float32 or float64)
    y = np.asarray(check_finite(y, "y"), float)
    y_hat = np.asarray(check_finite(y_hat, "y_hat"), float)
    peak = np.max(np.abs(y))
    if no_spread(y, eps):
        raise ValueError(
            "`y` is constant: the fit percent is undefined for an output with no spread "
            "(it compares the error with the spread of `y`)."
        )
    # Both divided by a power of two near the peak (exact): the norms of finite records
    # then neither overflow nor underflow whatever the data's units.
    scale = 2.0 ** -np.frexp(peak)[1]
    return fit_percent_unchecked(y * scale, y_hat * scale)


def fit_percent_unchecked(y: np.ndarray, y_hat: np.ndarray) -> float:
    """:func:`fit_percent` without its checks, for internal callers on checked NumPy arrays:
    a non-finite ``y_hat`` (a diverged simulation) gives ``nan``/``-inf`` rather than an
    error, and a constant ``y`` is compared with its mean's error alone."""
    den = np.linalg.norm(y - y.mean())
    return float(100.0 * (1.0 - np.linalg.norm(y - y_hat) / (den or 1.0)))


def _runs_of_equal(x: np.ndarray, tol: float):
    """``(start, stop, value)`` of every maximal run of consecutive samples equal up to
    ``tol``."""
    if x.size == 0:
        return []
    brk = np.flatnonzero(np.abs(np.diff(x)) > tol) + 1
    starts = np.concatenate([[0], brk])
    stops = np.concatenate([brk, [x.size]])
    return [(int(a), int(b), float(x[a])) for a, b in zip(starts, stops)]


def plateaus(y: np.ndarray, side: int, *, min_samples: int = 5, min_run: int = 3) -> dict | None:
    """Model-free clipping signature: the measured output sits *exactly* at its extreme
    value (``side`` +1: maximum, -1: minimum), repeatedly.

    A continuous signal plus noise never repeats a value; a quantised one repeats values
    at every level. So the signature requires at least ``min_samples`` samples at the
    extreme and, measured against the values other than the two extremes (a sensor
    clipped on both sides sits at its other limit too), either a run of at least
    ``min_run`` there at least twice as long as the longest run at any other value, or
    at least twice as many samples at the extreme as at any other value. The second form
    is a clip that a fast, noisy output touches on alternate samples (it leaves the limit
    on the noise and comes back): on the independent generator's records 1 of 24 clipped
    outputs had no run of three at its limit but 20 separate samples there. Returns
    ``{"level", "samples", "longest_run", "longest_run_elsewhere", "windows"}``
    (``windows``: the ``[start, stop)`` runs of two or more samples at the level; for a
    signature of separate samples, their groups at most 5 samples apart) or ``None``."""
    y = np.asarray(y, dtype=float)
    if y.size < 2:
        return None
    tol = 1e-9 * (float(np.ptp(y)) or 1.0)
    level = float(np.max(y) if side > 0 else np.min(y))
    other = float(np.min(y) if side > 0 else np.max(y))
    at = np.abs(y - level) <= tol
    if int(at.sum()) < min_samples:
        return None
    runs = _runs_of_equal(y, tol)
    on = [(a, b) for a, b, val in runs if abs(val - level) <= tol]
    longest = max((b - a for a, b in on), default=0)
    elsewhere = max((b - a for a, b, val in runs
                     if abs(val - level) > tol and abs(val - other) > tol), default=1)
    # how often any other value repeats: its runs once the values are sorted
    inner = np.sort(y[(np.abs(y - level) > tol) & (np.abs(y - other) > tol)])
    repeats = max((b - a for a, b, _ in _runs_of_equal(inner, tol)), default=1)
    by_run = longest >= min_run and longest >= 2 * elsewhere
    by_count = int(at.sum()) >= 2 * repeats
    if not (by_run or by_count):
        return None
    spots = ([[a, b] for a, b in on if b - a >= 2] if by_run
             else windows(at, min_gap=5, min_len=1, limit=len(at)))
    return {"level": level, "samples": int(at.sum()), "longest_run": int(longest),
            "longest_run_elsewhere": int(elsewhere), "windows": spots}
