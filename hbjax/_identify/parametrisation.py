"""The free parameters of the identification criteria: the gauge that fixes the gain
ambiguity ``(A, mu B, P/mu)`` (the paper's ``P2(-h_m) - P1(h_m) = 1``, section 4.1, or
``B(1) = 1``), the scaled coefficients the solver sees, touch equalities, and the codes of
the play operator's band rules.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .._core.backlash import power_columns
from .._core.model import Hammerstein
from .._core.params import model_from_theta
from .stable import a_from_free, free_from_a

# Band rules (an integer code passed where a boolean ``lower_is_p1`` used to be; ``False``
# and ``True`` are the two labelled rules).
LABELLED_P2_LOWER = 0
LABELLED_P1_LOWER = 1
CORE_BAND = 2  # L = min(P1, P2), H = max(P1, P2): the operator of hbjax.simulate


PAPER = "paper"  # P2(-h_m) - P1(h_m) = 1 (paper section 4.1)
STATIC_GAIN = "static_gain"  # B(1) = 1


class Parametrisation(eqx.Module):
    """Free parameters ``z`` <-> the normalised model, for one gauge.

    The input-output behaviour only fixes ``(A, mu B, P/mu)``; one linear equality removes
    the scale ``mu``:

    - ``gauge="paper"`` (``h_m`` given): ``P2(-h_m) - P1(h_m) = 1``, solved for ``c2_0``;
    - ``gauge="static_gain"``: ``B(1) = b_1 + ... + b_nb = 1``, solved for ``b_1``.

    ``lower_is_p1`` fixes which branch is the band's lower edge of the labelled band;
    ``core`` (default ``False``) selects the core operator ``L = min, H = max`` instead
    (:attr:`band`, :func:`hbjax._identify.criteria._internal`). ``touch_x`` / ``touch_on`` (optional) add linear
    equalities ``P1(x_k) = P2(x_k)`` at the scaled inputs ``x_k`` where ``touch_on``: the
    free parameters are projected onto them (:meth:`feasible`), so a solve stays on the
    models whose branches touch there.
    Internally the branches are evaluated in ``x = v / scale`` (``scale`` = largest
    ``|v|`` of the data), with scaled coefficients ``c_i scale^i``: the Jacobian columns
    then have comparable sizes, which the Levenberg–Marquardt damping assumes.
    """

    na: int = eqx.field(static=True)
    nb: int = eqx.field(static=True)
    m: int = eqx.field(static=True)
    gauge: str = eqx.field(static=True)
    scale: Float[Array, ""]
    h_m: Float[Array, ""]
    lower_is_p1: Bool[Array, ""]
    core: Bool[Array, ""] | bool = False
    touch_x: Float[Array, " k"] | None = None
    touch_on: Bool[Array, " k"] | None = None
    # ``stable``: ``z[:na]`` are the free parameters of a stable ``A`` (tanh of the
    # reflection coefficients, :mod:`hbjax._identify.stable`) instead of ``a`` itself.
    stable: bool = eqx.field(static=True, default=False)
    # ``"estimate"``: the criteria leave the unknown past out (:func:`residuals`).
    initial_state: str = eqx.field(static=True, default="zero")

    @property
    def band(self):
        """The band rule code of :func:`hbjax._identify.criteria._internal`."""
        return jnp.where(self.core, CORE_BAND, jnp.asarray(self.lower_is_p1).astype(jnp.int32))

    @property
    def size(self) -> int:
        """Number of parameters in the flattened model (a, b, c1, c2)."""
        return self.na + self.nb + 2 * self.m

    @property
    def eliminated(self) -> int:
        """Index (in flatten order) of the coefficient the equality constraint fixes."""
        return self.na + self.nb + self.m if self.gauge == PAPER else self.na

    def _powers(self):
        return self.scale ** jnp.arange(self.m)

    def constraint_row(self) -> Float[Array, " p"]:
        """``g`` with ``g^T theta = 1`` for the normalised (unscaled) ``theta``."""
        g = jnp.zeros(self.size)
        if self.gauge == PAPER:
            k = jnp.arange(self.m)
            off = self.na + self.nb
            g = g.at[off:off + self.m].set(-(self.h_m**k))
            g = g.at[off + self.m:].set((-self.h_m) ** k)
        else:
            g = g.at[self.na:self.na + self.nb].set(1.0)
        return g

    def theta_scaled(self, z: Float[Array, " q"]) -> Float[Array, " p"]:
        """Free parameters -> ``[a, b, c1 scale^i, c2 scale^i]`` satisfying the constraints."""
        return self._theta_scaled_free(self.feasible(z))

    def feasible(self, z: Float[Array, " q"]) -> Float[Array, " q"]:
        """The orthogonal projection of ``z`` onto the touch equalities (``z`` itself
        without any)."""
        if self.touch_x is None:
            return z
        zero = jnp.zeros_like(z)
        e = self._theta_scaled_free(zero)
        emat = jax.jacfwd(self._theta_scaled_free)(zero)  # affine map: constant
        pw = power_columns(self.touch_x, self.m)
        g = jnp.concatenate([jnp.zeros((pw.shape[0], self.na + self.nb), pw.dtype), pw, -pw],
                            axis=1) * self.touch_on[:, None]
        c, d = g @ emat, -(g @ e)
        return z - jnp.linalg.pinv(c) @ (c @ z - d)

    def _theta_scaled_free(self, z):
        if self.stable and self.na:
            z = jnp.concatenate([a_from_free(z[:self.na]), z[self.na:]])
        k = self.eliminated
        theta = jnp.concatenate([z[:k], jnp.zeros(1, z.dtype), z[k:]])
        g = self.constraint_row() * self._scaling_inverse()
        # g[k] is +1 in both gauges (c2_0 enters P2(-h_m) with weight 1; b_1 enters B(1)).
        return theta.at[k].set(1.0 - jnp.dot(g, theta))

    def _scaling(self):
        ones = jnp.ones(self.na + self.nb)
        return jnp.concatenate([ones, self._powers(), self._powers()])

    def _scaling_inverse(self):
        return 1.0 / self._scaling()

    def theta(self, z):
        """Free parameters -> normalised ``theta`` in :func:`hbjax.flatten_params` order."""
        return self.theta_scaled(z) * self._scaling_inverse()

    def free(self, theta):
        """Normalised ``theta`` -> free parameters (drops the eliminated coefficient)."""
        ts = theta * self._scaling()
        k = self.eliminated
        z = jnp.concatenate([ts[:k], ts[k + 1:]])
        if self.stable and self.na:
            z = jnp.concatenate([free_from_a(z[:self.na]), z[self.na:]])
        return z

    def jacobian(self) -> Float[Array, "p q"]:
        """``d theta / d z`` (constant: the parametrisation is affine; not for ``stable``)."""
        return jax.jacfwd(self.theta)(jnp.zeros(self.size - 1))

    def model(self, z) -> Hammerstein:
        return model_from_theta(self.theta(z), self.na, self.nb)
