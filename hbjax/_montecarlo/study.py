"""The :class:`Study` returned by :func:`hbjax.monte_carlo`: per-length statistics of the
normalised parameter estimates, and the log-log RMSE slope that checks consistency."""

import equinox as eqx
import numpy as np

from .._core import display
from .._misc import t_quantile
from .._results import message_of_code


def _slope_fit(lengths, rmse, mse_var):
    """Weighted least-squares fit of ``log RMSE = alpha + slope log N`` for every parameter.

    The weights are the inverse Monte Carlo variances of ``log RMSE`` (delta method,
    ``var(log RMSE) ~ var(e^2) / (4 R MSE^2)``), so the interval reflects how many
    realisations were run: a consistent, ``sqrt(N)``-rate estimator gives slopes near -1/2.
    Returns ``(slope, stderr)``, NaN where fewer than two lengths have a positive RMSE;
    where some length has no Monte Carlo variance (fewer than two valid realisations, or
    realisations all alike, as without noise), the slope is the unweighted fit and
    ``stderr`` is NaN: draws that do not differ measure no uncertainty.
    """
    n_len, n_par = rmse.shape
    slope = np.full(n_par, np.nan)
    stderr = np.full(n_par, np.nan)
    x = np.log(np.asarray(lengths, float))
    for p in range(n_par):
        ok = np.isfinite(rmse[:, p]) & (rmse[:, p] > 0)
        if ok.sum() < 2 or np.ptp(x[ok]) == 0:
            continue
        y = np.log(rmse[ok, p])
        if not np.all(np.isfinite(mse_var[ok, p]) & (mse_var[ok, p] > 0)):
            # (a zero variance would give an infinite weight and a zero-width interval)
            slope[p] = np.polyfit(x[ok], y, 1)[0]
            continue
        var_log = mse_var[ok, p] / (4.0 * rmse[ok, p] ** 4)
        w = 1.0 / var_log
        xw = np.sum(w * x[ok]) / np.sum(w)
        sxx = np.sum(w * (x[ok] - xw) ** 2)
        slope[p] = np.sum(w * (x[ok] - xw) * y) / sxx
        stderr[p] = np.sqrt(1.0 / sxx)
    return slope, stderr


class Study(eqx.Module):
    """Result of :func:`hbjax.monte_carlo`: statistics of the normalised estimates per
    record length and per parameter (order a, b, c1, c2, see :func:`hbjax.param_names`).

    Statistics use the valid realisations only (result code 0); the others are counted.

    - `lengths`: record lengths per experiment, shape ``(L,)``.
    - `names`: parameter names; `true`: true normalised values (:func:`hbjax.normalise`).
    - `mean`, `bias`, `std`, `rmse`: shape ``(L, P)``. `std` uses ``ddof=1``;
      ``rmse**2 = bias**2 + std**2 (R-1)/R``.
    - `n_valid`, `n_failed`: realisations used / excluded per length, shape ``(L,)``.
    - `codes`: result code of every realisation, shape ``(L, R)`` (see `failure_counts`).
    - `estimates`: raw normalised estimates ``(L, R, P)`` if ``keep_estimates=True``, else None.
    - `slope`, `slope_stderr`, `slope_ci`: fitted slope of ``log RMSE`` vs ``log N`` per
      parameter, its standard error (Monte Carlo uncertainty, delta method) and 95% interval
      ``(P, 2)``; -1/2 for a consistent estimator at the ``sqrt(N)`` rate.
    - `compile_seconds`, `run_seconds`: per length, compilation and execution wall time.
    - `realisations`, `noise_std`, `estimator`, `noise`, `n_devices`, `chunk_size`: settings.
    """

    lengths: np.ndarray
    names: tuple
    true: np.ndarray
    mean: np.ndarray
    bias: np.ndarray
    std: np.ndarray
    rmse: np.ndarray
    n_valid: np.ndarray
    n_failed: np.ndarray
    codes: np.ndarray
    estimates: np.ndarray | None
    slope: np.ndarray
    slope_stderr: np.ndarray
    slope_ci: np.ndarray
    compile_seconds: np.ndarray
    run_seconds: np.ndarray
    realisations: int
    noise_std: float
    estimator: str
    noise: str
    n_devices: int
    chunk_size: int

    @classmethod
    def from_estimates(cls, lengths, names, true, estimates, codes, *, keep_estimates, **settings):
        """Statistics from all estimates ``(L, R, P)`` and codes ``(L, R)``, computed on the
        host in a fixed order (the numbers do not depend on chunking or device count)."""
        estimates = np.asarray(estimates, float)
        codes = np.asarray(codes)
        valid = codes == 0
        n_valid = valid.sum(axis=1)
        errors = estimates - true[None, None, :]
        mask = valid[:, :, None]
        count = np.maximum(n_valid, 1)[:, None].astype(float)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(mask, estimates, 0.0).sum(axis=1) / count
            dev = np.where(mask, estimates - mean[:, None, :], 0.0)
            std = np.sqrt((dev**2).sum(axis=1) / np.maximum(n_valid - 1, 1)[:, None])
            sq = np.where(mask, errors**2, 0.0)
            mse = sq.sum(axis=1) / count
            # Monte Carlo variance of the MSE estimate, for the slope's interval.
            mse_var = ((np.where(mask, errors**2, 0.0) - mse[:, None, :]) ** 2 * mask).sum(
                axis=1
            ) / count / count
        empty = n_valid == 0
        mse_var[n_valid < 2] = np.nan  # one realisation: no Monte Carlo variance
        mean[empty] = np.nan
        mse[empty] = np.nan
        std[n_valid < 2] = np.nan
        rmse = np.sqrt(mse)
        # var(RMSE^2) -> var(RMSE) is handled inside the fit (delta method on log).
        slope, stderr = _slope_fit(lengths, rmse, mse_var)
        ci = np.stack([slope - 1.96 * stderr, slope + 1.96 * stderr], axis=1)
        return cls(
            lengths=np.asarray(lengths, int), names=tuple(names), true=np.asarray(true, float),
            mean=mean, bias=mean - true[None, :], std=std, rmse=rmse,
            n_valid=n_valid, n_failed=codes.shape[1] - n_valid, codes=codes,
            estimates=estimates if keep_estimates else None,
            slope=slope, slope_stderr=stderr, slope_ci=ci, **settings,
        )

    def failure_counts(self) -> dict[str, np.ndarray]:
        """Per failure message, the number of realisations per length with that code (read
        in :data:`hbjax.RESULTS`'s table, a custom estimator's too; a code outside it as
        ``code N``)."""
        out = {}
        for code in np.unique(self.codes):
            if code != 0:
                out[message_of_code(code)] = (self.codes == code).sum(axis=1)
        return out

    def table(self, file=None) -> str:
        """A readable table (bias, std, RMSE per length and parameter, then slopes);
        printed to ``file`` (default stdout) and returned."""
        lines = [
            f"Monte Carlo study: estimator={self.estimator}, noise={self.noise}, "
            f"noise_std={self.noise_std:g}, {self.realisations} realisations per length, "
            f"{self.n_devices} device(s)",
        ]
        head = f"{'param':>7} {'true':>10}" + "".join(
            f" | {'N=' + str(n):>33}" for n in self.lengths
        )
        sub = f"{'':>7} {'':>10}" + "".join(
            f" | {'bias':>10} {'std':>10} {'rmse':>10}" for _ in self.lengths
        )
        lines += [head, sub, "-" * len(sub)]
        for p, name in enumerate(self.names):
            row = f"{name:>7} {self.true[p]:>10.5g}"
            for i in range(len(self.lengths)):
                row += f" | {self.bias[i, p]:>10.3e} {self.std[i, p]:>10.3e} {self.rmse[i, p]:>10.3e}"
            lines.append(row)
        lines.append("-" * len(sub))
        lines.append("valid realisations: " + ", ".join(
            f"N={n}: {v}/{self.realisations}" for n, v in zip(self.lengths, self.n_valid)
        ))
        for msg, counts in self.failure_counts().items():
            lines.append(f"  failed ({msg}): {counts.tolist()}")
        lines.append("log-log RMSE slope vs N (95% CI; -0.5 = sqrt(N) consistency):")
        for p, name in enumerate(self.names):
            lo, hi = self.slope_ci[p]
            lines.append(f"{name:>7} {self.slope[p]:+.3f}  [{lo:+.3f}, {hi:+.3f}]")
        text = "\n".join(lines)
        print(text, file=file)
        return text

    def plot(self, **kwargs):
        """RMSE vs N on log-log axes with the ``N^-1/2`` reference, and per-parameter error
        histograms (when estimates were kept); see :func:`hbjax.plot.plot_monte_carlo`."""
        from .._plot.monte_carlo import plot_monte_carlo  # matplotlib only when plotting

        return plot_monte_carlo(self, **kwargs)

    def summary(self) -> display.Summary:
        """Per parameter: the true value, the mean estimate with its Monte Carlo standard
        error and 95% interval (Student's t over the valid realisations), bias, std and RMSE at the longest record, and the log-log
        RMSE slope with its 95% interval; then valid realisations and failures."""
        i = int(np.argmax(self.lengths))
        n = max(int(self.n_valid[i]), 1)
        num = display.format_number
        # Student's t with n - 1 degrees of freedom: 1.96 would cover a mean over 3 valid
        # realisations in 81 % of studies, not 95 %.
        factor = t_quantile(0.975, n - 1)
        rows = []
        for p, name in enumerate(self.names):
            se = self.std[i, p] / np.sqrt(n)
            lo, hi = self.mean[i, p] - factor * se, self.mean[i, p] + factor * se
            rows.append([name, num(self.true[p]), num(self.mean[i, p]), num(se),
                         f"[{num(lo)}, {num(hi)}]", num(self.bias[i, p]), num(self.std[i, p]),
                         num(self.rmse[i, p]), f"{self.slope[p]:+.3f}",
                         f"[{self.slope_ci[p, 0]:+.3f}, {self.slope_ci[p, 1]:+.3f}]"])
        table = display.Table(
            ["parameter", "true", "mean", "std err", "95% interval", "bias", "std", "rmse",
             "slope", "slope 95%"], rows, f"at N = {int(self.lengths[i])} (slope over all N; "
            "-0.5 = sqrt(N) consistency)")
        figures = {
            "estimator": self.estimator, "noise": f"{self.noise}, std {self.noise_std:g}",
            "record lengths N": self.lengths,
            "valid realisations": f"{self.n_valid.tolist()} of {self.realisations}",
            "devices": self.n_devices,
        }
        notes = [f"failed ({msg}): {counts.tolist()}"
                 for msg, counts in self.failure_counts().items()]
        return display.report("Monte Carlo study", figures=figures, tables=[table], notes=notes)

    def __repr__(self) -> str:
        return display.pformat(self, skip=("estimates", "codes", "compile_seconds",
                                           "run_seconds", "slope_stderr"))

    def _repr_html_(self) -> str:
        return self.summary()._repr_html_()
