"""One result enumeration for the whole package.

Every estimator reports how it ended with a member of :class:`RESULTS`: the closed form of
sections 4-5 (:func:`hbjax.identify_giri`), refinement (:func:`hbjax.refine`,
:func:`hbjax.fit`, :func:`hbjax.separable_ls`), the Monte Carlo study (``Study.codes`` holds
the members' integer values) and the diagnosis (a candidate that failed). As in optimistix,
codes are joined with :meth:`RESULTS.where` and ``throw=True`` is ``result.error_if(...)``
inside the compiled program, so it raises under ``jax.jit`` too.
"""

import equinox as eqx
import optimistix as optx


class RESULTS(optx.RESULTS):  # pyright: ignore
    """optimistix's result codes plus those of the closed form and of refinement."""

    # --- closed form (sections 4-5 of the paper) ---
    singular_ls = (
        "the least-squares system (26) is singular: v2 does not excite A, B* (does the "
        "+-h_m swing cross the backlash gap? assumption A4)"
    )
    unstable_a = (
        "the estimated A is unstable (assumption A3 fails): the records do not come from "
        "a stable system, so the offset (17) and the averages of stage 3 do not converge"
    )
    zero_static_gain = "B*(1) is not significantly different from 0 (assumption A5 fails)"
    singular_vandermonde = "the Vandermonde systems (45)-(46) are singular"
    gap_not_crossed = (
        "the data contradict the design: v = +h_m does not put the output on P1 and "
        "v = -h_m on P2 (P2*(-h_m) - P1*(h_m) should be 1); increase h_m (assumption A4), "
        "or, where the noise is at the sensor rather than in the equation (A6), which "
        "biases the closed form, identify with hbjax.fit"
    )
    # --- refinement ---
    gauge_undefined = (
        "the normalisation cannot be applied to the initial model: mu = P2(-h_m) - P1(h_m) "
        "is 0 (paper gauge) or B(1) is 0 (static-gain gauge)"
    )
    branches_cross = (
        "the refined branches P1 and P2 cross at recorded inputs where the crossing decides "
        "the output: the estimate's labelled band and the core operator (L = min, H = max) "
        "disagree on the data"
    )
    unstable = (
        "the identified linear block is unstable (a pole on or outside the unit circle; "
        "assumption A3): the model cannot be simulated; try other orders, more data, or "
        "criterion='simulation'"
    )
    poor_fit = (
        "the identified model's free-run simulation fit on its own estimation data is below "
        "the floor (0 %: worse than each record's mean, or `min_sim_fit`); see .sim_fit; try "
        "other orders (na, nb, m) or criterion='simulation'"
    )
    closing_loop = (
        "the branches meet or cross inside the recorded input range (a closing hysteresis "
        "loop) and the model does not reproduce the data (free-run fit below the floor, "
        "see .sim_fit): more excitation around the meeting point or another degree m"
    )
    no_input_effect = (
        "the model's input path does not predict the output significantly better than the "
        "output's own past values (see .residual_p[2], the p-value of no input effect): the "
        "records show no effect of the input at this noise level (e.g. slow poles integrating "
        "the equation noise, or an output unrelated to the input), or the estimate is a poor "
        "local optimum (try more starts: refine(..., restarts=64) or hbjax.fit)"
    )
    loop_unresolved = (
        "the branches meet or cross inside the recorded input range where both decide "
        "outputs (a hysteresis loop closing inside the data) and the estimate's own "
        "covariance leaves its free run uncertain by more than the tolerance (see .loop_spread, % of the "
        "output's spread): the records do not pin the loop; record longer, with less noise "
        "or more excitation around the meeting point (the model is returned with throw=False)"
    )
    branches_undetermined = (
        "the records do not determine the branches: the input holds too few distinct values "
        "where a branch decides the output (or never moves that branch), so some branch "
        "coefficients are unidentified (see .unidentified); the model reproduces the records "
        "but not the branches between or beyond the recorded values: record an input that "
        "moves through more values, or lower m (the model is returned with throw=False)"
    )
    branches_between_levels = (
        "the records determine the branches only at the recorded input values: between them, "
        "where a branch decides the output, its uncertainty (the estimate's covariance) is "
        "more than twice that at them (see .interpolation_ratio), as after an input of a few "
        "levels; the model reproduces the records but an input of other values can simulate "
        "far off: record an input that moves through more values, or lower m (the model is "
        "returned with throw=False)"
    )
    free_run_undetermined = (
        "the estimate's own covariance leaves its free run on the estimation records "
        "uncertain by more than the output's spread (see .free_run_spread, % of it): a "
        "parameter draw as likely as the estimate simulates the records worse than their "
        "mean, so the records do not determine the model (a short or noisy record, a static "
        "gain near 0); record longer or with less noise, or lower the orders (the model is "
        "returned with throw=False)"
    )


def message(result) -> str:
    """The words for a concrete result (``"success"`` for ``RESULTS.successful``)."""
    return RESULTS[result] or "success"


def code(result):
    """The integer value of a result (array of them for a batch): what ``Study.codes``
    stores. The one place that reads the enumeration's value."""
    return result._value


def message_of_code(value: int) -> str:
    """The words for an integer value taken from :func:`code`."""
    for name, item in RESULTS._name_to_item.items():
        if int(item._value) == int(value):
            return message(item)
    return f"code {int(value)}"


def raise_if_failed(res):
    """``res`` (a result with ``.model`` and ``.result``), raising when the compiled program
    runs unless ``res.result`` is successful: ``throw=True`` under ``jax.jit``, where a
    Python ``raise`` after the call cannot see the traced code (optimistix's pattern)."""
    failed = res.result != RESULTS.successful
    return eqx.tree_at(lambda r: r.model, res, res.result.error_if(res.model, failed))


__all__ = ["RESULTS", "code", "message", "message_of_code", "raise_if_failed"]
