"""Model validation on a recording, as MATLAB's ``compare``: free-run simulation or
``k``-step-ahead prediction against the measured output, with its fit percentage."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._core import display
from .._core.initial import (FreeRunOverflow, InitialState, estimate_initial_state, injection,
                             unstable_why)
from .._core.model import AbstractModel, Hammerstein, play_trajectory
from .._core.simulate import predict, simulate
from .._diagnose.residual_tests import fit_percent_unchecked
from .._misc import (MAX_MAGNITUDE, as_float_array, check_magnitude, float_dtype, is_traced,
                     lagged, no_spread, same_length)
from .recordings import as_input_output
from .refine_result import AbstractRefinement
from .stable import (INITIAL_STATES, check_estimated_start, check_initial_state,  # noqa: F401
                     start_response)
from .uncertainty import free_run_std


def check_horizon(horizon):
    if horizon is None:
        return None
    if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)):
        raise TypeError(f"`horizon` must be None or an integer >= 1, got {horizon!r}.")
    if horizon < 1:
        raise ValueError(f"`horizon` must be None (free run) or an integer >= 1, got {horizon}.")
    return int(horizon)


@eqx.filter_jit
def _ahead(model: Hammerstein, v, y, horizon: int, u0, past):
    """``y_hat(t | t - horizon)``: measured outputs up to ``t - horizon``, the model's own
    predictions after. With ``z_s(t)`` the ``s``-step prediction and ``z_r = y`` for
    ``r <= 0``: ``z_s(t) = -sum_i a_i z_{s-i}(t-i) + sum_j b_j u(t-j) + d(t)``, ``d`` the
    equation errors `past` (``None``: none) the record's past leaves at its first
    ``max(na, nb)`` samples."""
    arx = model.arx
    u = play_trajectory(model.backlash, v, u0)
    base = jnp.zeros_like(v)
    for j in range(arx.nb):
        base = base + arx.b[j] * lagged(u, j + 1)
    if past is not None:
        base = base.at[:past.shape[0]].add(past[:v.shape[0]])
    if arx.na == 0:
        return base

    def step(carry, _):
        z = base
        for i in range(arx.na):
            z = z - arx.a[i] * lagged(carry[i], i + 1)
        return (z,) + carry[:-1], None

    carry, _ = jax.lax.scan(step, (y,) * arx.na, None, length=horizon)
    return carry[0]


def predict_ahead(model: AbstractModel, v, y, horizon: int, *, u0=0.0, y0=None, past=None):
    """``horizon``-step-ahead prediction (1: :func:`hbjax.predict`; at least the record's
    length: the free run of :func:`hbjax.simulate`). `past`, if given, replaces `y0`: the
    equation errors at the first ``max(na, nb)`` samples that the record's past leaves
    (:func:`hammerstein_state`; any past, also input lags that are not the play state)."""
    if past is not None:
        dtype = float_dtype(model, v, y)
        past = jnp.asarray(past, dtype)
        if horizon >= int(np.shape(v)[0]):
            free = simulate(model, v, u0=u0).astype(dtype)
            h = start_response(model.arx.a.astype(dtype), model.arx.nb, free.shape[0], dtype)
            return free + h @ past
        return _ahead(model, jnp.asarray(v, dtype), jnp.asarray(y, dtype), horizon,
                      jnp.asarray(u0, dtype), past)
    if horizon >= int(np.shape(v)[0]):
        return simulate(model, v, u0=u0, y0=y0)
    if horizon == 1:
        return predict(model, v, y, u0=u0, y0=y0)
    if not isinstance(model, Hammerstein):
        raise TypeError(f"`horizon` > 1 needs an hbjax.Hammerstein model, got "
                        f"{type(model).__name__}.")
    # one dtype for the scan's carry: float32 records with a float64 model run in float64,
    # as hbjax.predict does
    dtype = float_dtype(model, v, y)
    v, y = jnp.asarray(v, dtype), jnp.asarray(y, dtype)
    u0 = jnp.asarray(u0, dtype)
    past = None if y0 is None else injection(model, jnp.asarray(y0, dtype), u0,
                                             max(model.arx.na, model.arx.nb))
    return _ahead(model, v, y, horizon, u0, past)


def _fit_text(fit: float) -> str:
    """A fit percentage as the summary prints it (a diverged model's in powers of ten)."""
    return f"{fit:.2f}" if abs(fit) < 1e6 else f"{fit:.3g}"


class Comparison(eqx.Module):
    """What :func:`compare` measured, one row per model.

    - `fit`: fit percentage ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` (a float for one
      model, an array with one entry per model for a list).
    - `rmse`: root-mean-square error ``||y - y_hat|| / sqrt(T)``, same shape.
    - `y_hat`: the model outputs, ``(T,)`` or ``(models, T)``.
    - `y`, `v`, `dt`: the recording (``dt`` in seconds or ``None``).
    - `y_std`: for a result of :func:`hbjax.refine` or :func:`hbjax.fit` compared freely,
      the standard deviation of its free run, sample by sample, that the estimate's own
      covariance implies (``result.free_run_std`` from the initial state used; the
      estimation error only, not the noise); ``NaN`` for a plain model or a prediction
      horizon. Same shape as `y_hat`.
    - `initial_states`: the :class:`hbjax.InitialState` used per model (``None`` for zero
      initial conditions). ``hbjax.simulate(model, v, u0=s.u0, y0=s.y0)`` reproduces the
      free run where ``nb <= na``; where ``nb > na`` the runs also hold the fitted input
      lags before the record, which ``(y0, u0)`` cannot express (its ``y0`` is their
      least-squares image; :func:`hammerstein_state`).
    - `names`, `horizon` (``None``: free run), `initial_state`.
    """

    fits: np.ndarray
    rmses: np.ndarray
    y_hats: np.ndarray
    y_stds: np.ndarray
    y: np.ndarray
    v: np.ndarray
    initial_states: tuple
    names: tuple = eqx.field(static=True)
    horizon: int | None = eqx.field(static=True)
    initial_state: str = eqx.field(static=True)
    dt: float | None = eqx.field(static=True)
    single: bool = eqx.field(static=True)

    @property
    def fit(self):
        return float(self.fits[0]) if self.single else self.fits

    @property
    def rmse(self):
        return float(self.rmses[0]) if self.single else self.rmses

    @property
    def y_hat(self):
        return self.y_hats[0] if self.single else self.y_hats

    @property
    def y_std(self):
        return self.y_stds[0] if self.single else self.y_stds

    def _spread(self, k) -> str:
        """Median free-run standard deviation of row ``k`` (``-`` where none)."""
        sd = self.y_stds[k]
        return "-" if np.all(np.isnan(sd)) else display.format_number(float(np.median(sd)))

    def summary(self) -> str:
        mode = "free run" if self.horizon is None else f"{self.horizon}-step-ahead prediction"
        lines = [(f"compare: {mode}, initial state {self.initial_state!r}, "
                 f"{self.y.shape[0]} samples"),
                 f"{'model':<16}{'fit %':>10}{'RMSE':>12}{'free-run sd':>13}{'u0':>12}  y0"]
        for k, (name, f, r, s) in enumerate(zip(self.names, self.fits, self.rmses,
                                                 self.initial_states)):
            u0 = "0" if s is None else f"{float(s.u0):.4g}"
            y0 = "zeros" if s is None else np.array2string(np.asarray(s.y0), precision=4)
            fit = _fit_text(f)
            lines.append(f"{name:<16}{fit:>10}{r:>12.4g}{self._spread(k):>13}{u0:>12}  {y0}")
        lines.append("free-run sd: median over the samples of the free run's standard deviation "
                     "its estimate's covariance implies (results of refine / fit only)")
        rows = [[str(n), _fit_text(f), display.format_number(r),
                 self._spread(k),
                 "0" if s is None else display.format_array(s.u0),
                 "zeros" if s is None else display.format_array(s.y0)]
                for k, (n, f, r, s) in enumerate(zip(self.names, self.fits, self.rmses,
                                                     self.initial_states))]
        table = display.Table(["model", "fit %", "RMSE", "free-run sd", "u0", "y0"], rows)
        html = display.report(lines[0], tables=[table])._repr_html_()
        return display.Summary("\n".join(lines), html)

    def _repr_html_(self) -> str:
        return self.summary()._repr_html_()

    def __repr__(self):
        fits = ", ".join(f"{n}: {f:.2f}%" for n, f in zip(self.names, self.fits))
        mode = "free run" if self.horizon is None else f"horizon={self.horizon}"
        return f"Comparison({fits}; {mode}, initial_state={self.initial_state!r})"


def _record(v, y):
    v, y, dt = as_input_output(v, y)
    v = as_float_array(v, "v", ndim=1)
    y = as_float_array(y, "y", ndim=1)
    same_length(v=v, y=y)
    if v.shape[0] < 2:
        raise ValueError(f"`v` and `y` must hold at least 2 samples, got {v.shape[0]}.")
    if is_traced(v) or is_traced(y):
        raise TypeError("`compare` works on concrete recordings; it cannot be jit-compiled.")
    if jax.config.read("jax_enable_x64"):
        # validation computes in float64, as identification does: a float32 record widened
        # here gives bitwise what widening it by hand gives (docs/robustness.md)
        v, y = v.astype(jnp.float64), y.astype(jnp.float64)
    # the fit's norms and the initial-state least squares overflow as the estimators' do
    return check_magnitude(v, "v"), check_magnitude(y, "y"), dt


def extension_state(model: AbstractModel, v, y):
    """Initial state of a model extension (a diagnosis effect: an :class:`hbjax.AbstractModel`
    with a ``base`` Hammerstein) and its free run from it.

    The play state ``u0`` is the base's (:func:`hbjax.estimate_initial_state` on the
    base); the unknown past then enters the base's linear block as an equation error at
    the first ``n = max(na, nb)`` samples, whose responses ``H`` (:func:`hbjax._identify.
    stable.start_response`) are fitted to the free-run error by least squares:
    ``y_hat = simulate(model, v, u0=u0) + H c``; of the base's play state and the
    convention's ``u0 = 0``, the one with the smaller squared error is kept. Exact for
    effects acting on the input or
    added to the linear block's output; a first-order account for effects inside the
    recursion. The returned :class:`InitialState` holds the base's output lags that give
    the same equation error (least squares when ``nb > na``)."""
    own = getattr(model, "estimate_start", None)
    if own is not None:  # an extension with a state of its own (e.g. two tank levels)
        return own(v, y)
    # The base's play state is estimated on an output that still holds the effect's own
    # term (an offset, a drift, a hum), which can pull it off; the convention's rest
    # (u0 = 0) is tried too, so the estimate never fits worse than the zero start (an
    # offset drift simulated from rest fitted 99.5 % from the base's state alone).
    return _general_past(model, model.base, v, y,
                         (estimate_initial_state(model.base, v, y).u0, 0.0))[:2]


def hammerstein_state(model: Hammerstein, v, y):
    """Initial state of a Hammerstein model and its free run from it.

    :func:`hbjax.estimate_initial_state` covers every past where ``nb <= na`` (the output
    lags span the equation errors the past leaves at the first ``n = na`` samples). Where
    ``nb > na`` it holds the input lags before the record at the play state (a system at
    rest in it), which a record cut from a longer run does not satisfy; there the past's
    ``n = nb`` equation errors are fitted freely, as for a model extension, from the
    estimated play state (MATLAB's ``'e'`` estimates the whole state too).

    **Returns:** ``(state, y_hat, past)``: the :class:`InitialState` (where ``nb > na``
    its ``y0`` is the least-squares image of the fitted past: a run from ``(y0, u0)``
    reproduces `y_hat` only where the past is one of a system at rest in its play state),
    the free run from the estimated start and the past's equation errors at the first
    ``nb`` samples (``None``, ``None`` where ``nb <= na``)."""
    state = estimate_initial_state(model, v, y)
    if model.arx.nb <= model.arx.na:
        return state, None, None
    return _general_past(model, model, v, y, (state.u0,))


def _general_past(model, base, v, y, play_states):
    """The free run of `model` from the best of `play_states`, plus the least-squares
    response of ``base``'s linear block to free equation errors at its first
    ``max(na, nb)`` samples: ``(InitialState, y_hat, equation errors)``."""
    dtype = jnp.result_type(v, y, base.arx.a)
    h = start_response(base.arx.a.astype(dtype), base.arx.nb, v.shape[0], dtype)
    best = None
    for u0 in play_states:
        u0 = jnp.asarray(u0, dtype)
        free = simulate(model, v, u0=u0).astype(dtype)
        coef = jnp.linalg.lstsq(h, y - free)[0]
        fitted = free + h @ coef
        cost = float(jnp.sum((y - fitted) ** 2))
        if best is None or cost < best[0]:
            best = (cost, u0, coef, fitted)
    _, u0, coef, y_hat = best
    return InitialState(_output_lags(base, u0, coef), u0, jnp.sum((y - y_hat) ** 2)), y_hat, coef


def _output_lags(base: Hammerstein, u0, past):
    """The output lags ``y0`` whose equation errors, with the input lags held at ``u0``,
    come nearest `past` (least squares; exact where the past is one of a system at rest
    in its play state)."""
    dtype = past.dtype
    n, na = past.shape[0], base.arx.na
    if not na:
        return jnp.zeros(0, dtype)
    lags = jax.jacfwd(lambda y0: injection(base, y0, jnp.zeros((), dtype), n))(
        jnp.zeros(na, dtype))
    # (a run from (y0, u0) also holds the input lags at u0: their part is not y0's)
    held = injection(base, jnp.zeros(na, dtype), u0, n)
    return jnp.linalg.lstsq(lags, past - held)[0]


@eqx.filter_jit
def _ahead_fits(model: Hammerstein, v, y, horizon: int, play_states):
    """Per play state in `play_states`: the squared error of the `horizon`-step predictor
    and the past's equation errors (its first ``max(na, nb)`` samples) that minimise it.
    The predictor is affine in those errors, so they are a least-squares solve."""
    zero = jnp.zeros(max(model.arx.na, model.arx.nb), v.dtype)

    def one(u0):
        run = lambda past: _ahead(model, v, y, horizon, u0, past)  # noqa: E731
        base, response = run(zero), jax.jacfwd(run)(zero)
        past = jnp.linalg.lstsq(response, y - base)[0]
        return jnp.sum((y - base - response @ past) ** 2), past

    # one state at a time: a batch would hold (states x errors x lags) records at once
    return jax.lax.map(one, play_states)


#: Beyond this many predictor steps (horizon x samples), the `horizon`-step state is sought
#: from the free run's play state and the convention's 0 only, not over a grid too: every
#: grid point costs a `horizon`-step prediction per past equation error.
_AHEAD_GRID_STEPS = 10_000_000


def ahead_state(model: Hammerstein, v, y, horizon: int, free_u0):
    """Initial state for :func:`compare`'s ``horizon``-step predictor, as MATLAB's
    ``'e'``, fitted to that predictor's own errors, not the free run's (a free-run start
    judged the predictor worse than a zero start on records a model cannot hold). Play
    states tried: the free run's `free_u0`, the convention's 0 and, where the record is not
    too long for it, a 33-point grid over the band at the first input refined once between
    the best point's neighbours; for each, the past's equation errors by least squares
    (:func:`_ahead_fits`). Since 0 is among them, the estimate never predicts worse than
    the zero start. **Returns:** ``(state, y_hat, past)`` as :func:`hammerstein_state`."""
    dtype = float_dtype(model, v, y)
    v, y = jnp.asarray(v, dtype), jnp.asarray(y, dtype)
    fixed = [float(free_u0), 0.0]
    states, costs, pasts = [], [], []

    def weigh(tried):
        more, more_pasts = _ahead_fits(model, v, y, horizon, jnp.asarray(tried, dtype))
        more = np.where(np.isfinite(more), np.asarray(more), np.inf)
        states.extend(tried), costs.extend(more), pasts.extend(more_pasts)
        return more

    if horizon * v.shape[0] > _AHEAD_GRID_STEPS:
        weigh(fixed)
    else:
        p1, p2 = float(model.backlash.p1(v[0])), float(model.backlash.p2(v[0]))
        lo, hi = min(p1, p2), max(p1, p2)
        grid = np.linspace(lo, hi, _PLAY_GRID)
        for _ in range(2):  # the same 35 states' shape both times: one compilation
            k = int(np.argmin(weigh(fixed + list(grid))[2:]))
            step = grid[1] - grid[0]
            grid = np.linspace(max(grid[k] - step, lo), min(grid[k] + step, hi), _PLAY_GRID)
    best = int(np.argmin(costs))  # all inf (an overflowing model): the free run's state
    u0, past = jnp.asarray(states[best], dtype), pasts[best]
    y_hat = _ahead(model, v, y, horizon, u0, past)
    state = InitialState(_output_lags(model, u0, past), u0, jnp.sum((y - y_hat) ** 2))
    return state, y_hat, past


_PLAY_GRID = 33


@eqx.filter_jit
def _prediction_sse(model, v, y, grid, skip: int):
    """Sum of squared one-step errors after `skip` samples, per play state in `grid`."""
    return jax.vmap(lambda u0: jnp.sum((y - predict(model, v, y, u0=u0))[skip:] ** 2))(grid)


def play_state_for_prediction(model: AbstractModel, base: Hammerstein, v, y, skip: int):
    """The play state ``u(-1)`` in the band ``[L(v(0)), H(v(0))]`` at the first input (the
    states the play can hold there; beyond an edge it starts from that edge) whose one-step
    predictions after the first `skip` samples fit best: a 33-point grid, then a second
    one between the best point's neighbours. The convention's ``0`` is kept where it fits
    as well, so a record from rest is scored as before."""
    dtype = jnp.result_type(v, y, base.arx.a)
    v, y = jnp.asarray(v, dtype), jnp.asarray(y, dtype)
    p1, p2 = float(base.backlash.p1(v[0])), float(base.backlash.p2(v[0]))
    lo, hi = min(p1, p2), max(p1, p2)
    best_u = 0.0
    best = float(_prediction_sse(model, v, y, jnp.zeros(1, dtype), skip)[0])
    grid = np.linspace(lo, hi, _PLAY_GRID)
    for _ in range(2):
        costs = np.asarray(_prediction_sse(model, v, y, jnp.asarray(grid, dtype), skip))
        k = int(np.argmin(costs))
        if costs[k] < best:
            best_u, best = float(grid[k]), float(costs[k])
        step = grid[1] - grid[0]
        grid = np.linspace(max(grid[k] - step, lo), min(grid[k] + step, hi), _PLAY_GRID)
    return best_u

def compare(model, v, y=None, *, initial_state: str = "estimate", horizon=None,
            names=None) -> Comparison:
    """Compare model outputs with a measured output, as MATLAB's ``compare``.

    Each model is run on ``v`` either freely (``horizon=None``: :func:`hbjax.simulate`) or
    as a ``horizon``-step-ahead predictor (measured outputs up to ``t - horizon``, the
    model's own outputs after; ``horizon=1`` is :func:`hbjax.predict`), and scored with
    the fit ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` and the RMSE.

    **Arguments:**

    - `model`: an :class:`hbjax.AbstractModel`, a result of :func:`hbjax.refine` or
      :func:`hbjax.fit` (its model, and with ``horizon=None`` the free run's standard
      deviation its covariance implies, ``.y_std``), or a list of these (one row each).
    - `v`, `y`: the recording; or an :class:`hbjax.Recording` as `v` (then `y` is omitted
      and the figure's time axis is in seconds when its ``dt`` is known).
    - `initial_state`: ``"estimate"`` (default; output lags and play state estimated per
      model by :func:`hbjax.estimate_initial_state`, as MATLAB's
      ``'InitialCondition', 'e'``: real records rarely start at rest at zero; where
      ``nb > na`` the input lags before the record are fitted too, as the past's
      equation errors at the first ``nb`` samples (:func:`hammerstein_state`); for a model
      extension such as a diagnosis effect, :func:`extension_state`: the base's play
      state and the past's response through the base's linear block by least squares,
      the predictors starting from the play state only; an extension with a state of its
      own, such as the two levels of the diagnosis's two-store level law, estimates it
      itself; with a `horizon` shorter than the record, a Hammerstein predictor's start
      is fitted to that predictor's own errors, :func:`ahead_state`) or ``"zero"`` (the
      paper's zero
      initial conditions).
    - `horizon`: ``None`` for the free run, or an integer ``>= 1``.
    - `names`: labels of the models (default ``model 0``, ``model 1``, ...).

    **Returns:** a :class:`Comparison` (``.fit``, ``.rmse``, ``.y_hat``, ``.y_std``,
    ``summary()``).
    """
    check_initial_state(initial_state)
    horizon = check_horizon(horizon)
    single = isinstance(model, (AbstractModel, AbstractRefinement))
    models = [model] if single else model
    if not isinstance(models, (list, tuple)) or not models:
        raise TypeError("`model` must be an hbjax model, a result of refine / fit, or a "
                        "non-empty list of them.")
    covariances = []
    for k, mdl in enumerate(models):
        if isinstance(mdl, AbstractRefinement):
            covariances.append(mdl.covariance)
            continue
        if not isinstance(mdl, AbstractModel):
            raise TypeError(f"`model[{k}]` must be an hbjax model or a result of refine / fit, "
                            f"got {type(mdl).__name__}.")
        covariances.append(None)
    models = [m.model if isinstance(m, AbstractRefinement) else m for m in models]
    if initial_state == "estimate":
        for k, mdl in enumerate(models):
            if not isinstance(mdl, Hammerstein) and not isinstance(
                    getattr(mdl, "base", None), Hammerstein):
                raise TypeError(
                    f"`initial_state='estimate'` needs hbjax.Hammerstein models or extensions "
                    f"of one (a `base` Hammerstein); `model[{k}]` is a "
                    f"{type(mdl).__name__}: pass initial_state='zero'.")
    if isinstance(names, (str, bytes)):  # iterable, but each character would be a label
        raise TypeError(f"`names` must be a list of labels, one per model, got the string {names!r}.")
    names = tuple(f"model {k}" for k in range(len(models))) if names is None else tuple(names)
    if len(names) != len(models):
        raise ValueError(f"`names` must have one entry per model ({len(models)}), "
                         f"got {len(names)}.")
    v, y, dt = _record(v, y)
    y_np = np.asarray(y)
    if initial_state == "estimate":
        for k, mdl in enumerate(models):
            base = mdl if isinstance(mdl, Hammerstein) else mdl.base
            check_estimated_start([(y_np, y_np)], base.arx.na, base.arx.nb, initial_state,
                                  name="y", judged="`model`" if single else f"`model[{k}]`")
    if no_spread(y_np):
        raise ValueError(
            "`y` is constant: the fit 100 (1 - ||y - y_hat|| / ||y - mean(y)||) is undefined "
            "for an output with no spread (compare the RMSE of the models' outputs instead).")
    fits, rmses, y_hats, y_stds, states = [], [], [], [], []
    for k, (mdl, cov) in enumerate(zip(models, covariances)):
        try:
            state, y_hat, y_std = _run(mdl, cov, v, y, initial_state, horizon)
        except ValueError as exc:
            if single:
                raise
            # name the list entry whose run failed
            raise type(exc)(str(exc).replace("`model`", f"`model[{k}]`")) from exc
        fits.append(fit_percent_unchecked(y_np, y_hat))
        rmses.append(float(np.sqrt(np.mean((y_np - y_hat) ** 2))))
        y_hats.append(y_hat)
        y_stds.append(y_std)
        states.append(state)
    return Comparison(np.asarray(fits), np.asarray(rmses), np.stack(y_hats), np.stack(y_stds),
                      y_np, np.asarray(v), tuple(states), names, horizon, initial_state, dt,
                      single)


def _run(model, covariance, v, y, initial_state, horizon):
    """One row of :func:`compare`: ``(initial state or None, y_hat, y_std)``. An output
    that overflows (an unstable model) is refused: its fit would be NaN."""
    state, kw = None, {}
    if initial_state == "zero":
        y_hat = simulate(model, v) if horizon is None else predict_ahead(model, v, y, horizon)
    elif not isinstance(model, Hammerstein):
        state, free_run = extension_state(model, v, y)
        kw = {"u0": state.u0}  # the predictors: the play state only
        y_hat = free_run if horizon is None else predict_ahead(model, v, y, horizon, **kw)
    elif horizon is not None and horizon < v.shape[0]:
        # the predictor's own start (the free run's play state is one candidate; a free run
        # that overflows offers none, while the predictor may still be finite)
        try:
            free_u0 = estimate_initial_state(model, v, y).u0
        except FreeRunOverflow:
            free_u0 = 0.0
        state, y_hat, _ = ahead_state(model, v, y, horizon, free_u0)
    else:  # the free run (a horizon as long as the record is one)
        state, y_hat, _ = hammerstein_state(model, v, y)
        kw = {"u0": state.u0, "y0": state.y0}
        if y_hat is None:
            y_hat = simulate(model, v, **kw)
    y_hat = np.asarray(y_hat)
    if not np.all(np.isfinite(y_hat)):
        first = int(np.flatnonzero(~np.isfinite(y_hat))[0])
        raise FreeRunOverflow(f"the output of `model` overflows to inf/NaN from sample {first} on: "
                         f"{unstable_why(model)}.")
    peak = float(np.max(np.abs(y_hat)))
    if peak > MAX_MAGNITUDE:
        # finite, but its squared error overflows: the fit would read -inf
        first = int(np.flatnonzero(np.abs(y_hat) > MAX_MAGNITUDE)[0])
        raise FreeRunOverflow(f"the output of `model` grows beyond {MAX_MAGNITUDE:.0e} from sample "
                         f"{first} on (up to {peak:.3g}), too large for the fit's sums of "
                         f"squares: {unstable_why(model)}.")
    y_std = np.full_like(y_hat, np.nan)
    if covariance is not None and horizon is None:
        y_std = np.asarray(free_run_std(model, covariance, v, **kw), y_hat.dtype)
    return state, y_hat, y_std
