"""Structure selection: the orders ``(na, nb, m)`` by information criteria and validation
fit, one :func:`hbjax.fit` per candidate (as MATLAB's ``arxstruc``/``selstruc``)."""

import itertools
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from .._core import display
from .._core.initial import FreeRunOverflow
from .._core.model import Hammerstein
from .._core.progress import check_progress, progress_bar
from .._core.simulate import predict, simulate
from .._results import RESULTS
from .._misc import no_spread, positive_int
from .compare import compare, hammerstein_state, play_state_for_prediction
from .fit import fit_unnoted
from .criteria import PREDICTION
from .fit_criterion import AUTO
from .recordings import as_recordings, check_branch_degree, check_criterion
from .stable import check_estimated_start, check_initial_state

RANKINGS = ("bic", "aic", "validation")


class StructureSelection(eqx.Module):
    """What :func:`select_structure` found: one row per candidate structure, best first.

    - `orders`: ``(na, nb, m)`` per row.
    - `params`: free parameters ``na + nb + 2m - 1`` (after the static-gain normalisation).
    - `loss`: mean squared criterion residual on the estimation records.
    - `bic`, `aic`: ``N ln(loss) + k ln N`` and ``N ln(loss) + 2k`` (``N`` samples).
    - `validation_fit`: mean free-run fit (%) on the validation records, from the initial
      state `initial_state` names (estimated by default; ``nan`` without validation
      records).
    - `success`: whether :func:`hbjax.fit` succeeded.
    - `ranked`: whether the row is ranked: a success, or a fit refused only because the
      records determine its branches at the recorded inputs alone
      (``RESULTS.branches_between_levels``: an input of a few levels). Such a fit reached
      its optimum, so its loss compares the orders, while its branches between the levels
      are not known. Rows not ranked come last.
    - `models`: the fitted models; `messages`: their result messages.
    - `best`: the first row's ``(na, nb, m)``, ``None`` when no row is ranked (no
      structure is selected from failed fits); `best_model`: the first row's model when
      its fit is a success (``None`` otherwise, e.g. for branches known only at the
      levels: see ``messages[0]``); `rank_by`: the ranking column.
    - `criterion`: the criterion every row was fitted and scored with;
      `criterion_choice`: with ``criterion="auto"``, how :func:`hbjax.fit` chose it on
      the largest structure (empty otherwise).
    """

    orders: tuple
    params: np.ndarray
    loss: np.ndarray
    bic: np.ndarray
    aic: np.ndarray
    validation_fit: np.ndarray
    success: np.ndarray
    ranked: np.ndarray
    models: tuple
    messages: tuple = eqx.field(static=True)
    rank_by: str = eqx.field(static=True)
    criterion: str = eqx.field(static=True)
    criterion_choice: str = eqx.field(static=True, default="")

    @property
    def best(self) -> tuple | None:
        return self.orders[0] if bool(self.ranked[0]) else None

    @property
    def best_model(self) -> Hammerstein | None:
        return self.models[0] if bool(self.success[0]) else None

    def summary(self) -> str:
        chosen = (f"best (na, nb, m) = {self.best}" if self.best is not None else
                  "no structure selected: every fit failed (see the result column)")
        if self.best is not None and not bool(self.success[0]):
            chosen += (" (its fit determines the branches at the recorded inputs only: "
                       "no best_model)")
        criterion = f"{self.criterion} criterion" + (
            f" (chosen on the largest structure: {self.criterion_choice})"
            if self.criterion_choice else "")
        lines = [(f"select_structure: {len(self.orders)} structures, {criterion}, "
                 f"ranked by {self.rank_by}; {chosen}"),
                 (f"{'na':>3}{'nb':>4}{'m':>3}{'k':>4}{'loss':>12}{'BIC':>12}{'AIC':>12}"
                 f"{'val. fit %':>12}  result")]
        for (na, nb, m), k, loss, bic, aic, vf, msg in zip(
                self.orders, self.params, self.loss, self.bic, self.aic,
                self.validation_fit, self.messages):
            lines.append(f"{na:>3}{nb:>4}{m:>3}{k:>4}{loss:>12.4g}{bic:>12.1f}{aic:>12.1f}"
                         f"{vf:>12.2f}  {msg}")
        rows = [[str(o), str(k), display.format_number(loss), f"{bic:.1f}", f"{aic:.1f}",
                 f"{vf:.2f}", msg] for o, k, loss, bic, aic, vf, msg in zip(
                     self.orders, self.params, self.loss, self.bic, self.aic,
                     self.validation_fit, self.messages)]
        table = display.Table(["(na, nb, m)", "k", "loss", "BIC", "AIC", "val. fit %",
                               "result"], rows)
        html = display.report(lines[0], tables=[table])._repr_html_()
        return display.Summary("\n".join(lines), html)

    def _repr_html_(self) -> str:
        return self.summary()._repr_html_()

    def __repr__(self):
        return (f"StructureSelection(best={self.best}, rank_by={self.rank_by!r}, "
                f"{len(self.orders)} structures)")


def _orders(x, name: str, minimum: int) -> tuple:
    """An order, a range or a sequence of orders -> a non-empty tuple of ints."""
    if isinstance(x, (int, np.integer)) and not isinstance(x, bool):
        values = (x,)
    elif isinstance(x, (range, list, tuple, np.ndarray)):
        values = tuple(np.asarray(x).ravel().tolist()) if isinstance(x, np.ndarray) else tuple(x)
    else:
        raise TypeError(f"`{name}` must be an integer, a range or a sequence of integers, "
                        f"got {x!r}.")
    if not values:
        raise ValueError(f"`{name}` is empty: give at least one order to try.")
    return tuple(sorted({positive_int(v, name, minimum=minimum) for v in values}))


def _loss(model, recordings, criterion, initial_state, skip):
    """Mean squared prediction (or simulation) error over all estimation records, after
    the first `skip` samples of each.

    With ``initial_state="estimate"`` each record's unknown start is estimated as
    :func:`hbjax.fit` leaves it out of its criterion: the predictor starts from the play
    state that predicts best, the free run from the state :func:`hbjax.compare`
    estimates. Scoring every structure from a zero start instead charged a record's
    offset to the first ``max(na, nb)`` one-step errors, so the larger ``na`` lost on a
    record with an output offset of 1000 (BIC picked ``na = 1`` over the true 2)."""
    total, count = 0.0, 0
    for v, y in recordings:
        if initial_state == "zero":
            y_hat = predict(model, v, y) if criterion == "prediction" else simulate(model, v)
        elif criterion == "prediction":
            n = max(model.arx.na, model.arx.nb)
            y_hat = predict(model, v, y, u0=play_state_for_prediction(model, model, v, y, n))
        else:
            state, y_hat, _ = hammerstein_state(model, v, y)
            if y_hat is None:  # (nb <= na: the state reproduces the free run)
                y_hat = simulate(model, v, u0=state.u0, y0=state.y0)
        total += float(jnp.sum((y[skip:] - y_hat[skip:]) ** 2))
        count += int(y.shape[0]) - skip
    return total / count, count


def _validation_fit(model, validation, initial_state):
    try:
        return float(np.mean([compare(model, v, y, initial_state=initial_state).fit
                              for v, y in validation]))
    except FreeRunOverflow:  # an unstable model
        return -np.inf


def _score(recs, val, a, b, c, key, starts, criterion, initial_state, skip, res=None):
    """One row of the table: fit the orders ``(a, b, c)`` (unless `res` is that fit
    already) and score them."""
    if res is None:
        res = fit_unnoted(recs, na=a, nb=b, m=c, key=key, starts=starts,
                          criterion=criterion, initial_state=initial_state, throw=False,
                          progress=False)
    ok = bool(res.result == RESULTS.successful)
    # (a fit whose branches are known at the levels only reached its optimum: its loss
    # still compares the orders; measured in tests/test_validation_tools.py)
    ranked = ok or bool(res.result == RESULTS.branches_between_levels)
    loss, n = _loss(res.model, recs, criterion, initial_state, skip) if ranked else (np.inf, 1)
    k = a + b + 2 * c - 1
    log_loss = math.log(loss) if 0 < loss < np.inf else (np.inf if loss else -np.inf)
    vfit = (_validation_fit(res.model, val, initial_state) if (ranked and val is not None)
            else np.nan)
    return ((a, b, c), k, loss, n * log_loss + k * math.log(n), n * log_loss + 2 * k, vfit,
            ok, ranked, res.model, res.message)


def select_structure(recordings, *, na, nb, m, key, criterion: str = "prediction",
                     validation=None, rank_by=None, starts: int = 32,
                     initial_state: str = "estimate",
                     progress: bool | dict = True) -> StructureSelection:
    """Select the orders ``(na, nb, m)`` of an HB-Hammerstein model from recordings.

    Every combination of the candidate orders is identified by :func:`hbjax.fit` (same
    `key` for all, so the structures are compared on common random starts) and scored by
    its loss (mean squared one-step prediction error, or simulation error with
    ``criterion="simulation"``) on the estimation records, BIC ``N ln(loss) + k ln N``,
    AIC ``N ln(loss) + 2k`` (``k = na + nb + 2m - 1`` free parameters after the
    normalisation ``B(1) = 1``) and, with `validation` records, the free-run fit (%) on
    them (:func:`hbjax.compare`, from the initial state `initial_state` names: estimated
    by default).

    **Arguments:**

    - `recordings`: estimation records, as for :func:`hbjax.fit`.
    - `na`, `nb`, `m`: candidate orders, each an integer, a ``range`` or a sequence.
    - `key`: a JAX PRNG key.
    - `criterion`: ``"prediction"`` (default), ``"simulation"`` (passed to
      :func:`hbjax.fit`) or ``"auto"``: :func:`hbjax.fit`'s own choice, made once on the
      largest structure of the grid (the one whose errors show the noise rather than
      missing dynamics), then used for every row, so that all losses are of one
      criterion. With noise at the sensor the prediction criterion is biased and, scored
      on its own loss, favours larger orders (measured on an independent generator: BIC
      picked an order above the true one in 6 of 7 such systems); ``"auto"`` reads the
      noise from the records.
    - `validation`: records not used for estimation, or ``None``.
    - `rank_by`: ``"bic"`` (default), ``"aic"`` or ``"validation"`` (highest validation
      fit first; needs `validation`). BIC is consistent (it picks the true orders as the
      data grow); the validation fit rarely separates the true orders from larger ones.
    - `starts`: starts per :func:`hbjax.fit`.
    - `initial_state`: ``"estimate"`` (default, as :func:`hbjax.fit`: each record's unknown
      start is estimated, and every structure is scored after the first ``max(na, nb)``
      samples of its largest candidate, so all are scored on the same samples) or
      ``"zero"`` (the paper's records from rest, scored from sample 0).
    - `progress`: a progress bar over the structures once the work takes more than 2 s
      (``False`` silences it; a dict passes tqdm options, see ``docs/performance.md``).

    **Returns:** a :class:`StructureSelection` table, best first, with ``.best`` the
    selected ``(na, nb, m)``.
    """
    check_criterion(criterion, also=(AUTO,))
    check_initial_state(initial_state)
    check_progress(progress)
    na_list = _orders(na, "na", 0)
    nb_list = _orders(nb, "nb", 1)
    m_list = _orders(m, "m", 1)
    for order in m_list:  # every one, before any fit runs
        check_branch_degree(order)
    recs = as_recordings(recordings, "recordings")
    val = None if validation is None else as_recordings(validation, "validation")
    for k, (_, y_val) in enumerate(val or ()):
        if no_spread(np.asarray(y_val)):
            raise ValueError(f"`validation` record {k} has a constant output `y`: its fit "
                             "percentage is undefined.")
    rank_by = "bic" if rank_by is None else rank_by
    if rank_by not in RANKINGS:
        raise ValueError(f"`rank_by` must be one of {RANKINGS}, got {rank_by!r}.")
    if rank_by == "validation" and val is None:
        raise ValueError("`rank_by='validation'` needs `validation` records.")
    grid = list(itertools.product(na_list, nb_list, m_list))
    skip = max(na_list[-1], nb_list[-1]) if initial_state == "estimate" else 0
    if val is not None:
        check_estimated_start(val, na_list[-1], nb_list[-1], initial_state, name="validation")
    check_estimated_start(recs, na_list[-1], nb_list[-1], initial_state)
    short = min(int(np.asarray(y).shape[0]) for _, y in recs)
    if short <= skip + 1:
        raise ValueError(f"`recordings`: the shortest record has {short} samples; scoring "
                         f"orders up to max(na, nb) = {skip} needs more than {skip + 1}.")
    choice, known = "", {}
    if criterion == AUTO:
        largest = fit_unnoted(recs, na=na_list[-1], nb=nb_list[-1], m=m_list[-1], key=key,
                              starts=starts, initial_state=initial_state, throw=False,
                              progress=False)
        criterion, choice = largest.criterion, largest.criterion_choice
        if criterion == PREDICTION:
            # "auto" kept its prediction fit: the row's own fit, the same starts and key
            # (an output-error result may be the refinement from that fit instead, which
            # the other rows do not get, so that row is fitted as the others are)
            known[grid[-1]] = largest
    rows = []
    with progress_bar(progress, total=len(grid), desc="select_structure") as bar:
        for a, b, c in grid:
            rows.append(_score(recs, val, a, b, c, key, starts, criterion, initial_state,
                               skip, known.get((a, b, c))))
            bar.update(1)
    column = {"bic": 3, "aic": 4}
    if rank_by == "validation":
        order = sorted(range(len(rows)), key=lambda i: (not rows[i][7], -rows[i][5], rows[i][3]))
    else:
        order = sorted(range(len(rows)), key=lambda i: (not rows[i][7], rows[i][column[rank_by]]))
    rows = [rows[i] for i in order]
    cols = list(zip(*rows))
    return StructureSelection(
        tuple(cols[0]), np.asarray(cols[1]), np.asarray(cols[2]), np.asarray(cols[3]),
        np.asarray(cols[4]), np.asarray(cols[5], float), np.asarray(cols[6]),
        np.asarray(cols[7]), tuple(cols[8]), tuple(cols[9]), rank_by, criterion, choice)
