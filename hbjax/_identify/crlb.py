"""Fisher information and the constrained Cramér–Rao lower bound of the normalised
parameters."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._core import display
from .._misc import is_traced, positive_float
from .._core.cache import ensure_compilation_cache
from .._core.precision import require_x64
from .criteria import outputs
from .parametrisation import PAPER, STATIC_GAIN, Parametrisation
from .._core.model import Hammerstein
from .._core.params import flatten_params, gauge_factor, model_from_theta
from .recordings import as_recordings, check_criterion, check_h_m, check_model


class CRLBResult(eqx.Module):
    """The Cramér–Rao bound of :func:`crlb`.

    - `fisher`: Fisher information ``J^T J / sigma^2`` of the parameters ``theta`` (order
      a, b, c1, c2 of :func:`hbjax.flatten_params`), shape ``(p, p)``; singular along the
      gain ambiguity.
    - `covariance`: the constrained bound ``U (U^T F U)^+ U^T`` (Stoica & Ng 1998),
      ``U`` an orthonormal basis of the directions the normalisation leaves free.
    - `constraint`: ``g`` with ``g^T theta = 1`` (the normalisation).
    - `gauge`: ``"paper"`` or ``"static_gain"``.
    """

    fisher: Float[Array, "p p"]
    covariance: Float[Array, "p p"]
    constraint: Float[Array, " p"]
    gauge: str = eqx.field(static=True)

    @property
    def std(self) -> Float[Array, " p"]:
        """Lower bound on the standard deviation of each normalised parameter."""
        return jnp.sqrt(jnp.maximum(jnp.diagonal(self.covariance), 0.0))

    def summary(self, names=None) -> display.Summary:
        """The bound on each parameter's standard deviation and its Fisher information;
        `names` defaults to ``theta1, theta2, ...`` (pass :func:`hbjax.param_names`)."""
        std = display.std_from_covariance(self.covariance)
        p = self.covariance.shape[-1]
        if isinstance(names, (str, bytes)):  # iterable, but each character would be a name
            raise TypeError(f"`names` must be a list of {p} parameter names, got the string "
                            f"{names!r}.")
        names = [f"theta{k + 1}" for k in range(p)] if names is None else list(names)
        if len(names) != p:
            raise ValueError(f"`names` must hold one name per parameter ({p}), got "
                             f"{len(names)}.")
        fisher = display.concrete(self.fisher)
        diag = None if fisher is None else np.diagonal(fisher, axis1=-2, axis2=-1)
        table = display.parameter_table(names, std, header="std bound",
                                        extra={"Fisher information": diag})
        return display.report("Cramér-Rao lower bound", figures={"gauge": self.gauge},
                              tables=[table])

    def __repr__(self) -> str:
        return display.pformat(self)

    def _repr_html_(self) -> str:
        return self.summary()._repr_html_()


def crlb_traceable(model: Hammerstein, recordings, *, noise_std, criterion="prediction",
                   h_m=None) -> CRLBResult:
    """Traceable core of :func:`crlb` (``recordings`` a tuple of ``(v, y)`` arrays)."""
    na, nb, m = model.arx.na, model.arx.nb, model.backlash.m
    gauge = STATIC_GAIN if h_m is None else PAPER
    par = Parametrisation(na, nb, m, gauge, jnp.asarray(1.0),
                          jnp.asarray(0.0 if h_m is None else h_m, jnp.float64),
                          jnp.asarray(True))
    theta = flatten_params(model)

    def outs(th):
        return jnp.concatenate(outputs(model_from_theta(th, model.arx.na, model.arx.nb), recordings, criterion))

    jac = jax.jacfwd(outs)(theta)
    # The information per unit noise variance: sigma enters only as a final scale, so a
    # tiny or huge noise_std cannot overflow the matrix that is inverted.
    info = jac.T @ jac
    variance = jnp.asarray(noise_std) ** 2
    fisher = info / variance
    g = par.constraint_row()
    # Orthonormal basis of the null space of g^T: the directions the constraint allows.
    _, _, vt = jnp.linalg.svd(g[None, :])
    basis = vt[1:].T
    reduced = basis.T @ info @ basis
    # Equilibrated before the pseudo-inverse: raw powers of v make the diagonal span many
    # decades (h_m = 10, m = 5: v^4 ~ 1e5), and a relative cut-off on the raw matrix would
    # drop directions the records do identify.
    d = jnp.sqrt(jnp.where(jnp.diagonal(reduced) > 0, jnp.diagonal(reduced), 1.0))
    inv = jnp.linalg.pinv(reduced / jnp.outer(d, d), hermitian=True) / jnp.outer(d, d)
    cov = variance * (basis @ inv @ basis.T)
    return CRLBResult(fisher, cov, g, gauge)


_crlb_jit = eqx.filter_jit(crlb_traceable)


def crlb(model: Hammerstein, recordings, *, noise_std, criterion: str = "prediction",
         h_m=None) -> CRLBResult:
    """Fisher information and Cramér–Rao lower bound for the normalised parameters.

    For white Gaussian noise of standard deviation ``sigma`` entering as the paper's
    equation error ``xi`` (``criterion="prediction"``) the log-likelihood of the records
    is that of the one-step prediction errors, so ``F = sum_t psi(t) psi(t)^T / sigma^2``
    with ``psi = d y_hat / d theta`` (``jax.jacfwd`` through the predictor, evaluated on
    the given records: the bound conditional on the observed regressors, which converges
    to the expected Fisher information with the record length). With
    ``criterion="simulation"`` the noise is white on the output and ``psi = d y_sim / d theta``.

    The normalisation (``P2(-h_m) - P1(h_m) = 1`` with `h_m`, ``B(1) = 1`` without) is
    one linear equality ``g^T theta = 1``, so the bound is the constrained CRLB
    ``U (U^T F U)^+ U^T`` with ``U`` spanning the null space of ``g^T``.

    **Arguments:**

    - `model`: the true model, already normalised (``hbjax.normalise(model, h_m)`` or
      :func:`hbjax.normalise_static_gain`); a model that violates the constraint is refused.
    - `recordings`: ``(v, y)`` pair(s); with the prediction criterion ``y`` should be a
      realisation of the model's output (the regressors contain it).
    - `noise_std`: ``sigma`` (> 0).
    - `criterion`, `h_m`: as :func:`hbjax.refine`.

    **Returns:** a :class:`CRLBResult`.
    """
    require_x64("crlb")
    ensure_compilation_cache()
    check_model(model)
    check_criterion(criterion)
    recs = as_recordings(recordings, model=model)
    h_m = check_h_m(h_m)
    if not is_traced(noise_std):
        sigma = positive_float(noise_std, "noise_std")
        if not 1e-150 <= sigma <= 1e150:
            raise ValueError(
                f"`noise_std` must lie in [1e-150, 1e150] (its square, the noise variance, "
                f"must be a normal float64), got {noise_std!r}; express the output in other "
                "units."
            )
    if not any(is_traced(x) for x in jax.tree_util.tree_leaves(model)) and not is_traced(h_m):
        _check_normalised(model, h_m)
    res = _crlb_jit(model, recs, noise_std=noise_std, criterion=criterion, h_m=h_m)
    if not is_traced(res.fisher):
        _check_identified(res)
    return res


def _check_identified(res):
    """A pseudo-inverse of a singular Fisher information gives finite numbers where the
    bound is infinite: refuse records that do not identify every free parameter."""
    fisher, g = np.asarray(res.fisher), np.asarray(res.constraint)
    basis = np.linalg.svd(g[None, :])[2][1:].T
    reduced = basis.T @ fisher @ basis
    d = np.sqrt(np.where(np.diagonal(reduced) > 0, np.diagonal(reduced), 1.0))
    ev = np.linalg.eigvalsh(reduced / np.outer(d, d))  # equilibrated, as the bound itself
    rank = int(np.sum(ev > 1e-12 * ev.max())) if ev.max() > 0 else 0
    if rank < ev.size:
        raise ValueError(
            f"the Fisher information is singular (rank {rank} of {ev.size} free parameters): "
            "the records do not identify every parameter (too short, or an input that leaves "
            "a branch unexcited), so the Cramer-Rao bound is infinite in some directions."
        )


def _check_normalised(model, h_m):
    if h_m is None:
        value, what, fix = float(np.sum(np.asarray(model.arx.b))), "B(1) = sum(b)", "hbjax.normalise_static_gain(model)"
    else:
        with jax.ensure_compile_time_eval():  # concrete even inside an outer jit
            value = float(gauge_factor(model.backlash.c1, model.backlash.c2, h_m))
        what, fix = "P2(-h_m) - P1(h_m)", "hbjax.normalise(model, h_m)"
    if not abs(value - 1.0) <= 1e-8:
        raise ValueError(
            f"`model` is not normalised: {what} = {value:.6g}, expected 1; pass {fix} "
            "(the bound depends on the normalisation)."
        )
