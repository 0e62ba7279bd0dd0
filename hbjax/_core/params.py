"""Flattening a model into its parameter vector, in the documented order a, b, c1, c2."""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._misc import as_float_array, check_finite, float_dtype, is_traced
from .arx import ARX
from .backlash import Backlash, polyval_ascending
from .model import Hammerstein


def _check_model(model, name):
    if not isinstance(model, Hammerstein):
        raise TypeError(f"`{name}` must be an hbjax.Hammerstein, got {type(model).__name__}.")


def flatten_params(model: Hammerstein) -> Float[Array, " p"]:
    """``[a_1..a_na, b_1..b_nb, c1_0..c1_{m-1}, c2_0..c2_{m-1}]``: the parameter order
    used by :func:`hbjax.crlb`, covariances and Monte Carlo studies."""
    _check_model(model, "model")
    return jnp.concatenate([model.arx.a, model.arx.b, model.backlash.c1, model.backlash.c2])


def unflatten_params(like: Hammerstein, theta) -> Hammerstein:
    """Inverse of :func:`flatten_params`, with the orders of ``like``."""
    _check_model(like, "like")
    na, nb, m = like.arx.na, like.arx.nb, like.backlash.m
    # The result has the template's precision (a float64 model stays float64).
    theta = as_float_array(theta, "theta", dtype=float_dtype(like, theta))
    if theta.shape != (na + nb + 2 * m,):
        raise ValueError(
            f"`theta` must have shape ({na + nb + 2 * m},) for na={na}, nb={nb}, m={m}, "
            f"got {tuple(theta.shape)}."
        )
    if not is_traced(theta):  # traced: left to the caller (optimisers probe freely)
        check_finite(theta, "theta")
    return model_from_theta(theta, na, nb)


def split_theta(theta, na: int, nb: int):
    """``(a, b, c1, c2)`` of a parameter vector in :func:`flatten_params` order (the one
    place that slices it; traceable, unchecked)."""
    m = (theta.shape[0] - na - nb) // 2
    return theta[:na], theta[na:na + nb], theta[na + nb:na + nb + m], theta[na + nb + m:]


def model_from_theta(theta, na: int, nb: int) -> Hammerstein:
    """The :class:`hbjax.Hammerstein` of a parameter vector in :func:`flatten_params`
    order (traceable; :func:`unflatten_params` is the checked public form)."""
    a, b, c1, c2 = split_theta(theta, na, nb)
    return Hammerstein(Backlash(c1, c2), ARX(a, b))


def gauge_factor(c1, c2, h_m):
    """``mu = P2(-h_m) - P1(h_m)``, the factor the paper's normalisation divides the
    branches by and multiplies ``B`` with (section 4.1, eqs. (11)-(13)); ``M2* - M1* = 1``
    afterwards. Traceable; evaluated eagerly under ``jax.ensure_compile_time_eval`` by the
    argument checks; NumPy coefficients and a number (an eager check) give a NumPy number
    without dispatching JAX operations."""
    if isinstance(c1, np.ndarray) and isinstance(c2, np.ndarray) and np.ndim(h_m) == 0:
        return (np.polynomial.polynomial.polyval(-h_m, c2)
                - np.polynomial.polynomial.polyval(h_m, c1))
    return polyval_ascending(c2, -h_m) - polyval_ascending(c1, h_m)


def param_names(model: Hammerstein) -> list[str]:
    """Names in :func:`flatten_params` order: ``a1.., b1.., c1_0.., c2_0..``."""
    _check_model(model, "model")
    na, nb, m = model.arx.na, model.arx.nb, model.backlash.m
    return ([f"a{i + 1}" for i in range(na)] + [f"b{i + 1}" for i in range(nb)]
            + [f"c1_{i}" for i in range(m)] + [f"c2_{i}" for i in range(m)])
