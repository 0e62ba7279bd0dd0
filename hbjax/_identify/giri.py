"""The paper's closed-form identification, sections 4-5: offset (16)-(17), least squares
(26) for ``A`` and ``B* = mu B``, Vandermonde solves (45)-(46) for ``C1*`` and ``C2*``."""

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._core import display
from .._core.arx import ARX
from .._core.backlash import Backlash
from .._core.cache import ensure_compilation_cache
from .._core.model import Hammerstein
from .._core.params import gauge_factor
from .._core.precision import require_x64
from .._core.signals import GiriDesign
from .._misc import as_float_array, check_bool, check_values, is_traced, lagged
from .._results import RESULTS, message, raise_if_failed
from .giri_band import project_onto_band
from .linear import arx_regressors, equilibrate, equilibrated_solve

# Result codes: members of the package's one enumeration (their integer values are what the
# Monte Carlo study stores per realisation).
SUCCESS = int(RESULTS.successful._value)
NONFINITE = int(RESULTS.nonfinite._value)
SINGULAR_LS = int(RESULTS.singular_ls._value)
ZERO_STATIC_GAIN = int(RESULTS.zero_static_gain._value)
GAP_NOT_CROSSED = int(RESULTS.gap_not_crossed._value)
SINGULAR_VANDERMONDE = int(RESULTS.singular_vandermonde._value)
UNSTABLE_A = int(RESULTS.unstable_a._value)
_COND_LIMIT = 1e12
# The normalisation makes P2*(-h_m) - P1*(h_m) = 1 (section 4.1); stage 3 measures both
# values independently, so a large departure means the +-h_m swing did not cross the gap.
_GAP_TOLERANCE = 0.5


class GiriResult(eqx.Module):
    """What :func:`identify_giri` found, and what a user needs to judge it.

    - `model`: the estimated normalised :class:`hbjax.Hammerstein` (``A``, ``B*``, ``P1*``, ``P2*``).
    - `offset`: ``ybar1``, the mean of the v1 experiment (eq. (17)).
    - `transient`: samples of ``y1`` discarded before averaging.
    - `samples_offset`, `rows_ls`, `plateaus`: samples used by each stage (plateaus per level).
    - `cond_ls`: condition number of the normal matrix of (26).
    - `cond_vandermonde`: condition numbers ``(raw, scaled)`` of the larger of (45)-(46).
    - `gap`: measured ``P2*(-h_m) - P1*(h_m)`` (1 when the design assumptions hold).
    - `noise_std`: residual standard deviation of the LS stage (estimate of ``std(xi)``).
    - `b_star_sum_std`: standard error of ``B*(1)``.
    - `band_shift`: largest change of a plateau value (in ``u*`` units) made to keep the
      branches a band at the design's inputs (0: the paper's solve of (45)-(46) already
      is one; see :mod:`hbjax._identify.giri_band`).
    - `static_gain_evidence`: what showed ``B*(1) != 0`` (assumption A5): ``"closed
      form"`` (its two readings, the default), or ``"three records"`` where those could
      not and the refinement of this model on all three records could
      (:func:`identify_giri`; the model is the closed form's either way).
    - `result`: a :class:`hbjax.RESULTS` member, ``RESULTS.successful`` on success (see
      `message`).
    """

    model: Hammerstein
    offset: Float[Array, ""]
    transient: Int[Array, ""]
    samples_offset: Int[Array, ""]
    rows_ls: int = eqx.field(static=True)
    plateaus: Int[Array, " 2m"]
    cond_ls: Float[Array, ""]
    cond_vandermonde: Float[Array, " 2"]
    gap: Float[Array, ""]
    noise_std: Float[Array, ""]
    b_star_sum_std: Float[Array, ""]
    band_shift: Float[Array, ""]
    result: RESULTS
    static_gain_evidence: str = eqx.field(static=True, default="closed form")

    @property
    def message(self) -> str:
        return message(self.result)

    def summary(self) -> display.Summary:
        """The normalised estimates, the design checks (gap, condition numbers) and the
        result message; a text table that renders as HTML in Jupyter."""
        return display.estimation_summary(self, "Closed-form identification (Giri et al.)")

    def __repr__(self) -> str:
        return display.pformat(self)

    def _repr_html_(self) -> str:
        return self.summary()._repr_html_()


def normalise(model: Hammerstein, h_m) -> Hammerstein:
    """The model in the paper's normalisation (section 4.1, eqs. (11)-(13)).

    ``M1 = P1(h_m)``, ``M2 = P2(-h_m)``, ``mu = M2 - M1``; returns
    ``(A, mu B, P1/mu, P2/mu)``, so that ``M2* - M1* = 1``. Input-output behaviour is
    unchanged (for ``u0 = 0``).
    """
    if not isinstance(model, Hammerstein):
        raise TypeError(f"`model` must be an hbjax.Hammerstein, got {type(model).__name__}.")
    if isinstance(h_m, (bool, np.bool_)) or getattr(h_m, "dtype", None) == bool:
        # (signals promote booleans; an amplitude of True is a mistake)
        raise TypeError(f"`h_m` must be a real number, got {h_m!r}.")
    h_m = as_float_array(h_m, "h_m", dtype=jnp.float64)
    if h_m.ndim != 0:
        raise ValueError(f"`h_m` must be a scalar, got shape {tuple(h_m.shape)}.")
    if is_traced(h_m):
        h_m = eqx.error_if(h_m, ~(h_m > 0), "`h_m` must be > 0.")
        h_m = eqx.error_if(h_m, ~jnp.isfinite(h_m), "`h_m` must be finite.")
    elif not float(h_m) > 0:
        raise ValueError(f"`h_m` must be > 0, got {float(h_m)}.")
    elif not math.isfinite(float(h_m)):
        raise ValueError(f"`h_m` must be finite, got {float(h_m)}.")
    bl = model.backlash
    if is_traced(h_m) or any(is_traced(c) for c in (bl.c1, bl.c2)):
        mu = gauge_factor(bl.c1, bl.c2, h_m)
    else:  # concrete: in NumPy (the eager JAX polynomial was most of monte_carlo's set-up)
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused below
            mu = jnp.asarray(gauge_factor(np.asarray(bl.c1), np.asarray(bl.c2), float(h_m)),
                             h_m.dtype)
    if is_traced(mu):
        mu = eqx.error_if(mu, mu == 0, "mu = P2(-h_m) - P1(h_m) is 0: cannot normalise.")
    elif float(mu) == 0.0:
        raise ValueError(
            "mu = P2(-h_m) - P1(h_m) is 0 for this `model` and `h_m`: the normalisation "
            "(section 4.1) cannot be applied; the +-h_m swing must cross the backlash gap."
        )
    elif not math.isfinite(float(mu)):
        raise ValueError(
            f"mu = P2(-h_m) - P1(h_m) overflows for `h_m` = {float(h_m):g}: the branches "
            "of `model` at +-h_m exceed float64; give h_m in the input's units."
        )
    return Hammerstein(Backlash(bl.c1 / mu, bl.c2 / mu), ARX(model.arx.a, model.arx.b * mu))


def _offset(y1, transient):
    t = jnp.arange(y1.shape[0])
    # v1(0) = 0, so the first sample is never on P1; the transient of A is discarded too.
    w = (t >= jnp.maximum(transient, 1)).astype(y1.dtype)
    count = jnp.sum(w)
    return jnp.sum(w * y1) / count, count.astype(int)


def _least_squares(design, y2, offset, offset_samples=None):
    """Eq. (26) on the regression (23), rows ``t = n..T-1``.

    With ``offset_samples`` (the samples of ``y1`` whose mean is `offset`, eq. (17)) the
    covariance of ``[a, b*]`` includes the offset's own error: the regression runs on
    ``y2 - offset``, and to first order an offset error ``d`` moves the estimate by
    ``-A(1) gram^-1 mean(phi) d``; ``d`` has the variance ``sigma^2 / (A(1)^2 N_1)`` of a
    mean of ``y1`` at rest (the noise's long-run variance through ``1/A``), so ``A(1)``
    cancels. Without it the standard error of ``B*(1)`` was too small by up to sqrt(2)
    on slow systems (a zero-gain system's z-score had a standard deviation of 1.39)."""
    n = design.n
    y_tilde = y2 - offset
    u_tilde = jnp.asarray(design.binary_internal(y2.shape[0]))
    # Before t = 0 the ARX block rests at zero, so y~(t<0) = -ybar1 and u~(t<0) = -M1*;
    # starting the rows at t = n uses recorded samples only.
    phi = arx_regressors(u_tilde, y_tilde, n, n)[n:]
    target = y_tilde[n:]
    rows = phi.shape[0]
    gram = phi.T @ phi / rows
    theta = equilibrated_solve(gram, phi.T @ target / rows, differentiable=True)
    gram_s, scale = equilibrate(gram)
    eig = jnp.linalg.eigvalsh(gram_s)
    cond = eig[-1] / jnp.maximum(eig[0], 1e-300)
    resid = target - phi @ theta
    noise_var = jnp.sum(resid**2) / jnp.maximum(rows - 2 * n, 1)
    gram_inv = jnp.linalg.inv(gram_s) / jnp.outer(scale, scale)
    cov = noise_var * gram_inv / rows
    if offset_samples is not None:
        # Column by column, multiply-adds only: a batched product's summation order may
        # differ between device layouts, and the closed form's bits must not
        # (tests/test_determinism.py).
        mean_phi = jnp.mean(phi, axis=0)
        lever = gram_inv[:, 0] * mean_phi[0]
        for k in range(1, 2 * n):
            lever = lever + gram_inv[:, k] * mean_phi[k]
        cov = cov + noise_var / offset_samples * (lever[:, None] * lever[None, :])
    b_cov = cov[n:, n:]
    b_sum_std = jnp.sqrt(jnp.maximum(jnp.sum(b_cov), 0.0))
    return theta[:n], theta[n:], cond, jnp.sqrt(noise_var), b_sum_std, rows, cov


def _transient_length(a, limit):
    """Smallest power of two K with ||C^K|| < 1e-10 for the companion matrix C of A:
    after K samples the step response of v1 has settled to machine-visible precision."""
    n = a.shape[0]
    companion = jnp.zeros((n, n)).at[0].set(-a)
    if n > 1:
        companion = companion.at[1:, :-1].set(jnp.eye(n - 1))

    def body(carry, _):
        power, k, done = carry
        settled = jnp.linalg.norm(power) < 1e-10
        k = jnp.where(done | settled, k, 2 * k)
        return (power @ power, k, done | settled), None

    (_, k, _), _ = jax.lax.scan(body, (companion, jnp.array(1), jnp.array(False)), None, length=40)
    return jnp.minimum(k, limit)


def _is_stable(a):
    """Assumption A3 by the Schur-Cohn step-down recursion (traceable, no eigenvalues):
    ``1 + a_1 z^-1 + ... + a_n z^-n`` has all zeros inside the unit circle iff every
    reflection coefficient has modulus < 1."""
    poly = jnp.concatenate([jnp.ones(1, a.dtype), a])
    stable = jnp.array(True)
    for i in range(a.shape[0], 0, -1):
        k = poly[i]
        stable = stable & (jnp.abs(k) < 1)
        denom = jnp.where(jnp.abs(k) < 1, 1 - k**2, 1.0)
        poly = (poly[:i] - k * poly[i:0:-1]) / denom
    return stable


def _vandermonde(levels, values, h_m):
    """Solve ``V c = values`` (eqs. (45)-(46)) in the scaled variable ``x = level / h_m``."""
    m = levels.shape[0]
    powers = jnp.arange(m)
    v_scaled = (levels[:, None] / h_m) ** powers[None, :]
    coef_scaled, *_ = jnp.linalg.lstsq(v_scaled, values)
    s = jnp.linalg.svd(v_scaled, compute_uv=False)
    s_raw = jnp.linalg.svd(levels[:, None] ** powers[None, :], compute_uv=False)
    return coef_scaled / h_m**powers, s_raw[0] / s_raw[-1], s[0] / s[-1]


def _stage3(design, y3, a, b_star_sum, noise_std, cov):
    n, m = design.n, design.m
    t_inst, j_inst = design.estimation_instants(y3.shape[0])
    # Elementwise, one lag after the other (no dot product over the lags: a batched dot's
    # summation order may differ between device layouts, and the closed form's bits must
    # not, tests/test_determinism.py).
    lags = [lagged(y3, i + 1) for i in range(n)]
    z = y3
    for i in range(n):
        z = z + a[i] * lags[i]
    onehot = (j_inst[None, :] == np.arange(2 * m)[:, None]).astype(float)
    counts = onehot.sum(axis=1)
    z_raw = (jnp.asarray(onehot) @ z[t_inst]) / counts
    # The staircase's own reading of B*(1): its plateau means are B*(1) P*(level) + mean xi,
    # and P2*(-h_m) - P1*(h_m) = 1 by the normalisation, so the mean at -h_m (j = m) minus
    # the mean at +h_m (j = 0) estimates B*(1). Its error is the noise's,
    # sigma^2 (1/c_m + 1/c_0), plus that of the estimated a it filters y3 with: the
    # reading moves by g_i per unit of a_i, g_i the difference of the two levels' mean
    # y3(t - i). That second part ties it to the v2 reading (the same a, b estimate):
    # without it a system whose B*(1) is 0 read a significant staircase gain from the
    # transients that the error of a leaves in z.
    level_means = [(jnp.asarray(onehot) @ lag[t_inst]) / counts for lag in lags]
    g = jnp.stack([means[m] - means[0] for means in level_means]) if n else jnp.zeros(
        0, y3.dtype)
    cov_aa, cov_ab = cov[:n, :n], cov[:n, n:]
    stair_gain = z_raw[m] - z_raw[0]
    stair_var = noise_std**2 * (1.0 / counts[m] + 1.0 / counts[0]) + g @ cov_aa @ g
    stair_cov_b = g @ jnp.sum(cov_ab, axis=1)
    z_bar = z_raw / b_star_sum
    levels_np = np.asarray(design.staircase_levels(), float)
    raw_gap = z_bar[m] - z_bar[0]
    # The paper's plateau values held to the design's premise (a band at every applied
    # input; see giri_band): changes nothing where the paper's values already form one.
    z_band = project_onto_band(z_bar, levels_np / design.h_m, m, raw_gap > 0)
    band_shift = jnp.max(jnp.abs(z_band - z_bar))
    z_bar = z_band
    levels = jnp.asarray(levels_np)
    c1, cond1_raw, cond1 = _vandermonde(levels[:m], z_bar[:m], design.h_m)
    c2, cond2_raw, cond2 = _vandermonde(levels[m:], z_bar[m:], design.h_m)
    conds = jnp.stack([jnp.maximum(cond1_raw, cond2_raw), jnp.maximum(cond1, cond2)])
    # Level j = 0 is +h_m on P1 and level j = m is -h_m on P2: M1* and M2*.
    gap = z_bar[m] - z_bar[0]
    return (c1, c2, conds, gap, jnp.asarray(counts.astype(int)), band_shift,
            (stair_gain, stair_var, stair_cov_b))


def _readings(b_sum, b_sum_std, stair):
    """The two readings of ``B*(1)``, the v2 regression's (26) and the staircase's gap
    (:func:`_stage3`), and their joint covariance: ``(r, cov)`` with ``r`` shape ``(2,)``."""
    stair_gain, stair_var, stair_cov_b = stair
    r = jnp.stack([b_sum, stair_gain])
    cov = jnp.array([[b_sum_std**2, stair_cov_b], [stair_cov_b, stair_var]])
    return r, cov


def _zero_static_gain(b_sum, b_sum_std, stair, b_star, contradicted):
    """Assumption A5 rejected: ``B*(1)`` is within 4 standard errors of 0 on the evidence of
    both records that measure it, the v2 regression (26) and the staircase's gap, pooled
    by generalised least squares with their joint covariance (:func:`_readings`).

    The v2 record alone excites ``B*`` by one-sample pulses of height ``mu`` every ``4n``
    samples; a slow ``A`` (``n = 4``, poles near 0.8) at an equation noise of 5 % of the
    output range left ``B*(1)`` within 4 standard errors there in 11 of 2100 runs of the
    independent generator (``benchmarks/identify_random.py --seed 5``), each of which
    refined from the closed form to the optimum: a valid system must not fail A5 for the
    weakness of one record. The regression's test stands alone where the pooled reading
    is not usable: a singular or non-finite covariance (relative to its diagonal, so in
    any unit), or readings that contradict each other (`contradicted`, the gap check:
    then the staircase reads ``B*(1)`` times a gap other than 1).
    """
    r, cov = _readings(b_sum, b_sum_std, stair)
    # the 2 x 2 inverse's weights, w = cov^-1 1 (up to the determinant, which cancels)
    w = jnp.stack([cov[1, 1] - cov[0, 1], cov[0, 0] - cov[0, 1]])
    total = jnp.sum(w)
    det = cov[0, 0] * cov[1, 1] - cov[0, 1] ** 2
    pooled = jnp.sum(w * r) / total
    pooled_std = jnp.sqrt(jnp.maximum(det / total, 0.0))
    usable = (jnp.isfinite(pooled) & jnp.isfinite(pooled_std) & ~contradicted
              & (det > 1e-10 * cov[0, 0] * cov[1, 1]) & (total > 1e-10 * (cov[0, 0] + cov[1, 1])))
    pooled = jnp.where(usable, pooled, b_sum)
    pooled_std = jnp.where(usable, pooled_std, b_sum_std)
    return jnp.abs(pooled) <= 4 * pooled_std + 1e-8 * jnp.sum(jnp.abs(b_star))


def _gap_contradicted(gap, b_sum, b_sum_std, stair):
    """The data contradict the design's premise ``P2*(-h_m) - P1*(h_m) = 1``: the measured
    gap (the staircase's reading of ``B*(1)`` over the v2 regression's) is off by more than
    :data:`_GAP_TOLERANCE` *and* the two readings differ by more than 4 standard errors of
    their difference (joint covariance, :func:`_readings`). A gap off only as far as the
    noise of two weak readings puts it is no contradiction."""
    r, cov = _readings(b_sum, b_sum_std, stair)
    spread = jnp.sqrt(jnp.maximum(cov[0, 0] + cov[1, 1] - 2 * cov[0, 1], 0.0))
    significant = ~(jnp.abs(r[1] - r[0]) <= 4 * spread)  # NaN counts as significant
    return ~(jnp.abs(gap - 1.0) <= _GAP_TOLERANCE) & significant


def estimate_giri(design: GiriDesign, y1, y2, y3, transient=None) -> GiriResult:
    """Traceable core of :func:`identify_giri`: never raises on values, sets `result`."""
    finite = jnp.all(jnp.isfinite(y1)) & jnp.all(jnp.isfinite(y2)) & jnp.all(jnp.isfinite(y3))
    if transient is None:
        # A first offset from the second half of y1 (past any transient), then the
        # transient length from the estimated A, then the final offset.
        half = y1.shape[0] // 2
        offset0, _ = _offset(y1, half)
        a0, *_ = _least_squares(design, y2, offset0)
        transient = _transient_length(a0, half)
    transient = jnp.asarray(transient)
    offset, used = _offset(y1, transient)
    a, b_star, cond_ls, noise_std, b_sum_std, rows, cov = _least_squares(design, y2, offset,
                                                                         used)
    b_sum = jnp.sum(b_star)
    c1, c2, cond_v, gap, plateaus, band_shift, stair = _stage3(
        design, y3, a, b_sum, noise_std, cov)
    model = Hammerstein(Backlash(c1, c2), ARX(a, b_star))
    params = jnp.concatenate([a, b_star, c1, c2])
    contradicted = _gap_contradicted(gap, b_sum, b_sum_std, stair)
    zero_gain = _zero_static_gain(b_sum, b_sum_std, stair, b_star, contradicted)
    # The first failing check names the result (checks in the order the stages run).
    checks = [
        (~finite, RESULTS.nonfinite),
        (~(cond_ls < _COND_LIMIT), RESULTS.singular_ls),
        (~_is_stable(a), RESULTS.unstable_a),
        (zero_gain, RESULTS.zero_static_gain),
        (~jnp.all(jnp.isfinite(params)) | ~(cond_v[1] < _COND_LIMIT), RESULTS.singular_vandermonde),
        (contradicted, RESULTS.gap_not_crossed),
    ]
    code = RESULTS.successful
    for failed, item in reversed(checks):
        code = RESULTS.where(failed, item, code)
    return GiriResult(
        model, offset, transient, used, rows, plateaus, cond_ls, cond_v, gap, noise_std,
        b_sum_std, band_shift, code,
    )


_estimate_jit = eqx.filter_jit(estimate_giri)


# |B*(1)| in standard errors of the refinement on all three records that lifts the closed
# form's refusal of A5: the closed form's own level (:func:`_zero_static_gain`).
_A5_REFINED_Z = 4.0


def _static_gain_on_all_records(design, res, outputs):
    """The closed form's refusal of A5 (``B*(1)`` within 4 standard errors of 0 on its two
    readings), tried again on the evidence of all three records: the closed form's model
    refined on them (:func:`hbjax.refine`, paper normalisation). The refusal is lifted,
    the closed form's result standing with its model unchanged (the paper's), only where
    that refinement is a success, its one-step errors pass the whiteness and independence
    tests of :func:`hbjax.resid` on every record, and it puts ``B*(1)`` at least
    :data:`_A5_REFINED_Z` of its own standard errors from 0.

    Why: the closed form reads ``B*(1)`` from the v2 pulses and the staircase's plateau
    ends only, while the prediction errors of every sample carry it. On slow systems
    (``A(1)`` 0.003-0.05) the closed form's readings sat 0.5-2.5 standard errors from 0
    where the refinement put ``B*(1)`` about 7 away (``benchmarks/identify_random.py
    --seed 7``; ``benchmarks/RESULTS.md``). The residual tests are what keep a system whose
    ``B(1)`` is 0 refused: from its closed form the refinement can stop in a local
    minimum (hundreds to 10^6 sigma^2 above the truth's cost) whose ``B*(1)`` is many of
    its standard errors from 0, and whose errors are far from white.
    Only eager calls: under ``jit``/``vmap`` (:func:`estimate_giri`, the Monte Carlo
    studies) the closed form's own test decides.
    """
    # refine normalises through this module: imported here, where the two meet.
    from .refine import refine, residuals_suspect

    inputs = (design.constant_input, design.binary_input, design.staircase_input)
    records = [(make(y.shape[0]), y) for make, y in zip(inputs, outputs)]
    try:
        # (no random restarts: a refusal is judged on this model's refinement alone)
        refined = refine(res.model, records, h_m=design.h_m, restarts=0, throw=False)
    except ValueError:  # a start refine cannot take (mu = 0, non-finite): the refusal stands
        return res
    if residuals_suspect(refined, records, "prediction"):  # (also: not a success)
        return res
    n = design.n
    se = math.sqrt(max(float(np.sum(np.asarray(refined.covariance)[n:2 * n, n:2 * n])), 0.0))
    gain = float(np.sum(np.asarray(refined.model.arx.b)))
    if not (math.isfinite(se) and se > 0 and abs(gain) >= _A5_REFINED_Z * se):
        return res
    return dataclasses.replace(res, result=RESULTS.successful,
                               static_gain_evidence="three records")


def _record(y, name, minimum, what):
    y = as_float_array(y, name, ndim=1, dtype=jnp.float64)
    if y.shape[0] < minimum:
        raise ValueError(
            f"`{name}` has {y.shape[0]} samples; it must cover at least {what} "
            f"({minimum} samples)."
        )
    return check_values(y, name, output=True)


def _check_input_record(design, v, name, expected):
    v = np.asarray(as_float_array(v, name, ndim=1, dtype=jnp.float64))
    if name == "v2":
        off = ~np.isclose(np.abs(v), design.h_m, rtol=0, atol=1e-12 * design.h_m)
        if off.any():
            i = int(np.flatnonzero(off)[0])
            raise ValueError(
                f"`v2` must take values in {{-h_m, +h_m}} = {{{-design.h_m}, {design.h_m}}}; "
                f"sample {i} is {v[i]}."
            )
    if v.shape != expected.shape:
        where = f"length {v.shape[0]} vs {expected.shape[0]}"
    else:
        # One tolerance both decides and locates the first offending sample, so a small
        # offset is reported rather than missed by a looser search.
        off = np.flatnonzero(~np.isclose(v, expected, rtol=0, atol=1e-12 * design.h_m))
        where = f"first difference at sample {off[0]}" if off.size else None
    if where is not None:
        raise ValueError(
            f"`{name}` is not the design's signal ({where}); generate it with GiriDesign."
        )


def identify_giri(design: GiriDesign, y1, y2, y3, *, v1=None, v2=None, v3=None,
                  transient=None, throw=True) -> GiriResult:
    """Identify the normalised HB-Hammerstein model from the paper's three experiments.

    1. Offset ``ybar1``: mean of ``y1`` (response to ``v1``, eq. (14)) after discarding a
       transient, eqs. (16)-(17).
    2. ``theta* = [a, b*]`` by least squares (26) on the regression (23) built from ``y2``
       (response to ``v2``, eq. (27)), with ``u~`` known from eq. (28).
    3. ``C1*``, ``C2*`` from ``y3`` (response to ``v3``, eq. (32)): at the last sample of
       each plateau ``A(q^-1) y(t) = B*(1) P*(level) + xi(t)``; averaging over periods and
       solving the Vandermonde systems (45)-(46) (in the scaled variable ``level/h_m``).

    **Arguments:**

    - `design`: the :class:`hbjax.GiriDesign` the experiments were run with.
    - `y1`, `y2`, `y3`: the three output records (any lengths, each at least one period).
    - `v1`, `v2`, `v3`: optionally the applied inputs, checked against the design.
    - `transient`: samples of ``y1`` to discard; by default the settling time of the
      estimated ``A`` (smallest power of two with ``||C^K|| < 1e-10``, C the companion
      matrix), at most half the record.
    - `throw`: raise ``ValueError`` on failure (default); otherwise inspect ``.result``.

    **Returns:** a :class:`GiriResult`.
    """
    require_x64("identify_giri")
    ensure_compilation_cache()
    throw = check_bool(throw, "throw")
    if not isinstance(design, GiriDesign):
        raise TypeError(f"`design` must be an hbjax.GiriDesign, got {type(design).__name__}.")
    y1 = _record(y1, "y1", 4, "a few samples of the v1 step")
    y2 = _record(y2, "y2", design.binary_period, "one period 4n of v2")
    y3 = _record(y3, "y3", design.staircase_period, "one period 2m(n+1) of v3")
    for name, v, y, make in (("v1", v1, y1, design.constant_input),
                             ("v2", v2, y2, design.binary_input),
                             ("v3", v3, y3, design.staircase_input)):
        if v is not None:
            _check_input_record(design, v, name, make(y.shape[0]))
    if transient is not None:
        if isinstance(transient, bool) or not isinstance(transient, (int, np.integer)) or transient < 0:
            raise ValueError(f"`transient` must be a non-negative integer, got {transient!r}.")
        if transient >= y1.shape[0] - 1:
            raise ValueError(f"`transient` ({transient}) leaves no sample of `y1` ({y1.shape[0]}).")
    res = _estimate_jit(design, y1, y2, y3, transient)
    if not is_traced(res.result._value) and res.result == RESULTS.zero_static_gain:
        res = _static_gain_on_all_records(design, res, (y1, y2, y3))
    if throw and is_traced(res.result._value):
        return raise_if_failed(res)
    if throw and res.result != RESULTS.successful:
        raise ValueError(f"identify_giri failed: {res.message}.")
    return res
