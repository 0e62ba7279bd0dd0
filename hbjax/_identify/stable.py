"""Searching within stable models, and the initial state inside the fit criteria.

**Stability (assumption A3) by construction.** ``A = 1 + a_1 q^-1 + ... + a_na q^-na`` is
stable (all poles strictly inside the unit circle) if and only if its reflection (PARCOR)
coefficients satisfy ``|k_i| < 1`` (Schur-Cohn; :func:`hbjax._identify.quality.
reflection_coefficients` is the step-down recursion). :func:`a_from_free` maps free
parameters ``zeta`` to ``k_i = tanh(zeta_i)`` and ``k`` to ``a`` by the Levinson step-up
recursion: every real ``zeta`` gives a stable ``A`` and every stable ``A`` has exactly one
``zeta`` (:func:`free_from_a`). A Levenberg–Marquardt search in ``zeta`` therefore never
leaves the stable models; an unstable start is projected onto them by clipping its
reflection coefficients to ``|k| <= K_START``.

**Initial state inside the criteria.** Real records rarely start at rest. With
``initial_state="estimate"`` the criteria do not charge the model for the unknown past:

- prediction errors of eq. (10) whose regressors reach before the first sample
  (``t < max(na, nb)``) are left out (zero residual): the conditional likelihood;
- output errors (free run) have the response to the past removed by least squares. A
  past enters the free run only as an equation error ``d(t)``, ``t < n = max(na, nb)``
  (:mod:`hbjax._core.initial`), so its response is spanned by the ``n`` columns
  ``H = 1/A [e_0, ..., e_{n-1}]`` (unit impulses at the first ``n`` samples) and the
  residual is ``r - H (H^T H)^-1 H^T r`` for the current ``A``: the initial output and
  input lags estimated for every parameter value (variable projection), differentiable.
  The play operator's state ``u(-1)`` stays at the convention's 0 inside the criterion;
  :func:`hbjax.estimate_initial_state` also searches it for the reported fit figures.

Everything here is traceable (jit/vmap/jacfwd) and never raises on values.
"""

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._core.arx import all_pole

INITIAL_STATES = ("zero", "estimate")
# An unstable start's reflection coefficients are clipped to this modulus.
K_START = 0.999
# A stable start keeps its own (a pole within 1e-12 of the unit circle is moved there only
# so that arctanh stays finite): clipping those too to K_START moved a lightly damped
# optimum (k = -0.99965, poles of modulus 0.9963) to a model of 7 times its cost, so a
# start refined from an optimum began elsewhere.
K_INSIDE = 1.0 - 1e-12


def step_up(k: Float[Array, " na"]) -> Float[Array, " na"]:
    """Levinson step-up: reflection coefficients ``k`` -> ``a`` (inverse of
    :func:`hbjax._identify.quality.reflection_coefficients`):
    ``a^(i) = [a^(i-1) + k_i rev(a^(i-1)), k_i]``."""
    a = jnp.zeros(0, k.dtype)
    for i in range(k.shape[0]):
        a = jnp.concatenate([a + k[i] * a[::-1], k[i:i + 1]])
    return a


def check_initial_state(initial_state) -> str:
    """``initial_state``: one of :data:`INITIAL_STATES`."""
    if not isinstance(initial_state, str) or initial_state not in INITIAL_STATES:
        raise ValueError(
            f"`initial_state` must be one of {INITIAL_STATES}, got {initial_state!r}."
        )
    return initial_state


def check_estimated_start(recordings, na: int, nb: int, initial_state: str,
                          name: str = "recordings", judged: str = "") -> None:
    """Refuse a record too short to be judged from an estimated start: the start holds
    ``max(na, nb) + 1`` numbers (the past's equation errors and the play state), and a
    record with no more than twice as many samples would be fitted by the start alone and
    call any model a near-100 % free-run fit. The one home of this rule: `fit`, `refine`,
    `select_structure` (training and validation records) and `compare` call it; `judged`
    names the model being judged where there are several."""
    if initial_state != "estimate":
        return
    need = 2 * (max(na, nb) + 1)
    for k, (v, _) in enumerate(recordings):
        if int(v.shape[0]) < need:
            tag = f"{name}[{k}]" if len(recordings) > 1 else name
            of = f" ({judged})" if judged else ""
            raise ValueError(
                f"`{tag}` holds {int(v.shape[0])} samples, too few for "
                f"initial_state='estimate' with max(na, nb) = {max(na, nb)}{of}: its "
                f"estimated start fits up to {need // 2} numbers; give at least {need} "
                f"samples, or initial_state='zero'.")


def a_from_free(zeta: Float[Array, " na"]) -> Float[Array, " na"]:
    """Free parameters -> a stable ``a`` (``k = tanh(zeta)``, step-up)."""
    return step_up(jnp.tanh(zeta))


def free_from_a(a: Float[Array, " na"]) -> Float[Array, " na"]:
    """``a`` -> free parameters; an unstable (or marginal) ``A`` is first projected onto
    the stable models by clipping its reflection coefficients to ``|k| <= K_START``; a
    stable ``A`` maps to its own free parameters (:data:`K_INSIDE`)."""
    from .quality import reflection_coefficients  # quality -> criteria -> this module

    if a.shape[0] == 0:
        return a
    k = reflection_coefficients(a)
    k = jnp.where(jnp.isfinite(k), k, 0.0)
    bound = jnp.where(jnp.abs(k) < 1.0, K_INSIDE, K_START)
    return jnp.arctanh(jnp.clip(k, -bound, bound))


def start_response(a: Float[Array, " na"], nb: int, length: int, dtype) -> Array:
    """``H`` (``length x n``, ``n = max(na, nb)``): the free responses of ``1/A`` to unit
    equation errors at ``t = 0..n-1``, which span every past's effect on the free run."""
    n = max(a.shape[0], nb)
    e = jnp.eye(length, n, dtype=dtype)
    return all_pole(a, e)


def remove_start(r: Float[Array, " time"], a, nb: int, criterion: str, mask=None):
    """The residual ``r`` of one record with the unknown past's contribution removed
    (module docstring): prediction errors before ``max(na, nb)`` zeroed; output errors
    projected off the span of :func:`start_response`. ``mask`` marks recorded samples
    of a padded record (``None``: all)."""
    n = max(a.shape[0], nb)
    if n == 0:
        return r
    if criterion == "prediction":
        return r.at[:n].set(0.0)
    h = start_response(a, nb, r.shape[0], r.dtype)
    if mask is not None:
        h = jnp.where(mask[:, None], h, 0.0)
    gram = h.T @ h
    ridge = 1e-12 * jnp.trace(gram) / n + jnp.finfo(r.dtype).tiny
    coef = jnp.linalg.solve(gram + ridge * jnp.eye(n, dtype=r.dtype), h.T @ r)
    return r - h @ coef
