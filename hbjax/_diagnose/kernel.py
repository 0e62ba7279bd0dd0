"""One simulator for the HB-Hammerstein model with every diagnosis extension at once.

Every effect of the diagnosis library is a term of a single extended model whose neutral
values (zero coefficients, infinite clip levels, zero delay, change time past the end)
give back the nominal model of paper eq. (10) exactly. The effect classes of
effects (:mod:`.kernel_effect`) and the diagnosis fits all call :func:`simulate_full` and
:func:`whiten`, so one compiled function serves every candidate of a base structure
``(na, nb, m)``; which parameters a candidate may move is data (a selection matrix),
not structure.

Extended model (all terms together), with ``s(t) = 1[t >= tau]``:

- input path: ``u(t) = HB(P1 + s dP1 + c1x (v/vs)^m, P2 + s dP2 + c2x (v/vs)^m)(v)``,
  ``u_s = clip(u, in_lo, in_hi)``, delayed by ``d`` extra samples (``u_s(t) = 0`` for
  ``t < 0``);
- linear block: ``(A + s dA + ax q^-(na+1)) y_lin = (B + s dB + bx q^-(nb+1)) q^-d u_s + xi_c``
  with the equation error coloured by ``D(q^-1) xi_c = xi``;
- output path: ``y = clip(y_lin + drift + sinusoid + g(y_lin) + F_c tanh(du/w), out_lo, out_hi)``
  (the drift linear or settling, :func:`drift`).

The prediction error used by every fit is ``eps = D (A_t (y - y_pre))`` with ``y_pre`` the
simulated output before the output clip: for the nominal model it is exactly the ARX
equation error ``A y - B u`` (zero initial conditions), the maximum-likelihood criterion
under white Gaussian equation error. The output clip then acts on the *prediction*, as a
sensor's limit acts on the measurement: the predictor is ``clip(y - eps_pre, out_lo,
out_hi)`` (:func:`clipped_error`). Clipping inside the difference instead
(``A (y - clip(y_pre))``) would meet every exit from the clip with the free run's
accumulated output error and hide a clip from the prediction criterion on a slow plant
(benchmarks/RESULTS.md, "the clipped predictor").
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._core.arx import equation_error
from .._core.backlash import (
    gather_play,
    play_sources,
    play_step,
    polyval_ascending,
    power_columns,
    source_edges,
)
from .._core.params import flatten_params, model_from_theta, split_theta
from .._misc import is_traced, lag_sum, lagged

#: largest extra delay (samples) the extended simulator can represent
MAX_DELAY = 12

# consts vector: [v_scale, y_center, y_scale, friction_width]
N_CONSTS = 4


class Layout(NamedTuple):
    """Where each parameter sits in the flat extended parameter vector ``theta``.

    The first :attr:`p_base` entries are the base block: the model's parameter vector
    ``[a, b, c1, c2]`` of :func:`hbjax.flatten_params`, the vector every estimator works
    on (:mod:`hbjax._core.params` slices it and builds the model from it). The extension
    slots follow; neutral values switch each one off."""

    na: int
    nb: int
    m: int

    @classmethod
    def of(cls, model) -> Layout:
        """The layout of a :class:`hbjax.Hammerstein`'s orders."""
        return cls(model.arx.na, model.arx.nb, model.backlash.m)

    @property
    def p_base(self) -> int:
        return self.na + self.nb + 2 * self.m

    def slots(self) -> dict[str, tuple[int, int]]:
        sizes = [
            ("a", self.na), ("b", self.nb), ("c1", self.m), ("c2", self.m),
            ("a_extra", 1), ("b_extra", 1), ("c1_extra", 1), ("c2_extra", 1),
            ("da", self.na), ("db", self.nb), ("dc1", self.m), ("dc2", self.m),
            ("in_lo", 1), ("in_hi", 1), ("out_lo", 1), ("out_hi", 1),
            ("drift_offset", 1), ("drift_rate", 1), ("drift_decay", 1),
            ("sin_freq", 1), ("sin_cos", 1), ("sin_sin", 1),
            ("nl2", 1), ("nl3", 1), ("friction", 1), ("noise_d", 2),
        ]
        out, k = {}, 0
        for name, n in sizes:
            out[name] = (k, k + n)
            k += n
        return out

    @property
    def size(self) -> int:
        return max(stop for _, stop in self.slots().values())

    def get(self, theta, name):
        start, stop = self.slots()[name]
        return theta[start:stop]

    def base(self, theta):
        """``(a, b, c1, c2)`` of the base block (:func:`hbjax._core.params.split_theta`)."""
        return split_theta(theta[:self.p_base], self.na, self.nb)

    def model(self, theta):
        """The base :class:`hbjax.Hammerstein` of an extended vector."""
        return model_from_theta(theta[:self.p_base], self.na, self.nb)

    def neutral(self, model):
        """``theta`` of the nominal ``model``: its parameter vector in the base block, every
        extension switched off."""
        theta = jnp.zeros(self.size).at[:self.p_base].set(flatten_params(model))
        for name in ("in_lo", "out_lo"):
            theta = self.put(theta, name, -jnp.inf)
        for name in ("in_hi", "out_hi"):
            theta = self.put(theta, name, jnp.inf)
        return theta

    def put(self, theta, name, value):
        start, stop = self.slots()[name]
        if is_traced(theta) or is_traced(value):
            value = jnp.broadcast_to(jnp.asarray(value, theta.dtype), (stop - start,))
            return theta.at[start:stop].set(value)
        # Concrete vectors (the candidates' starts, built eagerly) are edited on the host:
        # an eager scatter costs about half a millisecond, and a diagnosis makes hundreds.
        out = np.array(theta)  # a copy: the caller's vector is left as it was
        out[start:stop] = value
        return jnp.asarray(out)


def _branch(c, dc, cx, s, v, vs, m):
    return polyval_ascending(c + s * dc, v) + cx * (v / vs) ** m


def simulate_full(lay: Layout, theta, ints, consts, v, noise, u0, clip: bool = True):
    """Free-run output of the extended model and the (clipped, delayed) internal signal.

    ``ints = [d, tau]`` (extra delay, change time), ``consts = [v_scale, y_center,
    y_scale, friction_width]``. Returns ``(y, u_used)``, each shape ``(T,)``;
    ``clip=False`` leaves out the output clip (the predictor's ``y_pre``).
    """
    na, nb, m = lay.na, lay.nb, lay.m
    g = lambda name: lay.get(theta, name)  # noqa: E731
    a, b, c1, c2 = lay.base(theta)
    a = jnp.concatenate([a, g("a_extra")])
    b = jnp.concatenate([b, g("b_extra")])
    da = jnp.concatenate([g("da"), jnp.zeros(1)])
    db = jnp.concatenate([g("db"), jnp.zeros(1)])
    dc1, dc2 = g("dc1"), g("dc2")
    c1x, c2x = g("c1_extra")[0], g("c2_extra")[0]
    in_lo, in_hi = g("in_lo")[0], g("in_hi")[0]
    nd = g("noise_d")
    delay, tau = ints[0], ints[1]
    vs = consts[0]
    T = v.shape[0]
    t_idx = jnp.arange(T)
    s_all = (t_idx >= tau).astype(v.dtype)
    zero = jnp.zeros((), v.dtype)
    buf_len = MAX_DELAY + nb + 2

    def step(carry, inputs):
        u_play, y_lags, u_buf, xi_lags = carry
        v_t, xi_t, s = inputs
        xi_c = xi_t - nd[0] * xi_lags[0] - nd[1] * xi_lags[1]
        u_del = jax.lax.dynamic_slice(u_buf, (delay,), (nb + 1,))
        y_t = xi_c
        for i in range(na + 1):
            y_t = y_t - (a[i] + s * da[i]) * y_lags[i]
        for i in range(nb + 1):
            y_t = y_t + (b[i] + s * db[i]) * u_del[i]
        p1 = _branch(c1, dc1, c1x, s, v_t, vs, m)
        p2 = _branch(c2, dc2, c2x, s, v_t, vs, m)
        u_t = play_step(u_play, jnp.minimum(p1, p2), jnp.maximum(p1, p2))
        u_sat = jnp.clip(u_t, in_lo, in_hi)
        u_buf = jnp.concatenate([u_sat[None], u_buf[:-1]])
        u_used = jax.lax.dynamic_index_in_dim(u_buf, delay, keepdims=False)
        return (u_t, (y_t,) + y_lags[:-1], u_buf, (xi_c, xi_lags[0])), (y_t, u_used)

    init = (jnp.asarray(u0, v.dtype), (zero,) * (na + 1), jnp.zeros(buf_len, v.dtype),
            (zero, zero))
    _, (y_lin, u_used) = jax.lax.scan(step, init, (v, noise, s_all))
    return output_path(lay, theta, consts, y_lin, u_used, clip), u_used


def drift(lay: Layout, theta, t):
    """The output drift ``offset + rate (1 - exp(-k t)) / k`` at times ``t`` (samples) and
    its derivatives with respect to ``rate`` and ``k`` (``drift_decay``): a drift that
    settles with time constant ``1 / k`` (thermal settling), linear (``offset + rate t``)
    at ``k = 0``, where it is computed as exactly that. ``(1 - exp(-x)) / x`` is written
    ``-expm1(-x) / x`` and by its series near ``x = 0``; ``x = k t`` is held above -30
    so a growing drift (``k < 0``) cannot overflow."""
    offset, rate, k = (lay.get(theta, name)[0] for name in
                       ("drift_offset", "drift_rate", "drift_decay"))
    x = jnp.maximum(k * t, -30.0)
    small = jnp.abs(x) < 1e-6
    xs = jnp.where(small, 1.0, x)  # the other branch's argument, kept finite
    phi = jnp.where(small, 1.0 - x / 2 + x * x / 6, -jnp.expm1(-xs) / xs)
    dphi = jnp.where(small, -0.5 + x / 3, (jnp.exp(-xs) * (1.0 + xs) - 1.0) / xs**2)
    return offset + rate * (t * phi), t * phi, rate * t * t * dphi


def output_path(lay: Layout, theta, consts, y_lin, u_used, clip: bool = True):
    """Additive and static output-side terms, then the output clip (unless ``clip=False``)."""
    g = lambda name: lay.get(theta, name)[0]  # noqa: E731
    t = jnp.arange(y_lin.shape[0], dtype=y_lin.dtype)
    y = y_lin + drift(lay, theta, t)[0]
    phase = 2 * math.pi * g("sin_freq") * t
    y = y + g("sin_cos") * jnp.cos(phase) + g("sin_sin") * jnp.sin(phase)
    z = (y_lin - consts[1]) / consts[2]
    y = y + consts[2] * (g("nl2") * z**2 + g("nl3") * z**3)
    du = u_used - jnp.concatenate([u_used[:1], u_used[:-1]])
    y = y + g("friction") * jnp.tanh(du / consts[3])
    return output_clip(lay, theta, y) if clip else y


def output_clip(lay: Layout, theta, x):
    """``x`` clipped to the output levels ``[out_lo, out_hi]``."""
    return jnp.clip(x, lay.get(theta, "out_lo")[0], lay.get(theta, "out_hi")[0])


def clipped_error(lay: Layout, theta, y, eps_pre):
    """One-step error of the predictor ``clip(y - eps_pre, out_lo, out_hi)``: the output
    clip applied to the prediction of the unclipped model (see module docstring); equal
    to ``eps_pre`` where the clip levels are infinite."""
    return y - output_clip(lay, theta, y - eps_pre)


def whiten(lay: Layout, theta, ints, y, y_pre):
    """Prediction error of the extended model from its unclipped free run ``y_pre``:
    ``D(q^-1) A_t(q^-1) (y - y_pre)``, then the output clip on the prediction
    (:func:`clipped_error`; see module docstring)."""
    s = (jnp.arange(y.shape[0]) >= ints[1]).astype(y.dtype)
    _, a_t, _ = linear_block(lay, theta, s)
    e = y - y_pre
    w = e + lag_sum(a_t, e)
    return clipped_error(lay, theta, y, w + lag_sum(lay.get(theta, "noise_d"), w))


def prediction_error(lay: Layout, theta, ints, consts, v, y):
    """``(eps, y_sim, u_used)`` of the extended model on a record (noise-free simulation)."""
    y_pre, u_used = simulate_full(lay, theta, ints, consts, v, jnp.zeros_like(v), 0.0,
                                  clip=False)
    return whiten(lay, theta, ints, y, y_pre), output_clip(lay, theta, y_pre), u_used


# --- Fast criterion for fitting --------------------------------------------------------
#
# The fits never run the simulator's scan with tangents. Two facts make every derivative a
# vectorised expression:
# - the play operator's output is always a branch value at the last sample where the
#   clamp was active: u(t) = L(v(k)) or H(v(k)). A primal-only scan finds k(t) and the
#   side; u is then a gather of branch values, differentiable in the branch coefficients;
# - with y_lin = (B/A) u the prediction error D A (y - y_sim) equals
#   D [A (y - d - g) - B u], where d are the additive output terms and g the deviation of
#   the static output map (curvature; the clip too for the output error, while the
#   predictor clips its prediction, see the module docstring); only g needs y_lin, which
#   is computed by an FFT division (exact up to the tail of the impulse response past
#   the padded length).



def iir_fft(a, num):
    """``num / A(q^-1)`` with zero initial conditions along the first axis (columns
    independent), by FFT on a padded grid: the fits' differentiable form of
    :func:`hbjax._core.arx.all_pole` (no scan to differentiate through)."""
    T = num.shape[0]
    nfft = 1 << (2 * T - 1).bit_length()
    den = jnp.fft.rfft(jnp.concatenate([jnp.ones(1), a]), nfft)
    den = den.reshape(den.shape + (1,) * (num.ndim - 1))
    return jnp.fft.irfft(jnp.fft.rfft(num, nfft, axis=0) / den, nfft, axis=0)[:T]


def linear_block(lay: Layout, theta, s):
    """``(a, a_t, b_t)`` of the extended linear block: ``a`` with the extra lag, and the
    per-sample coefficients ``a + s da``, ``b + s db`` (rows: lags; columns: samples)
    that :func:`hbjax._misc.lag_sum` applies (the base block's ``A``, ``B`` of eq. (10)
    when the extensions are neutral)."""
    a, b, _, _ = lay.base(theta)
    a = jnp.concatenate([a, lay.get(theta, "a_extra")])
    b = jnp.concatenate([b, lay.get(theta, "b_extra")])
    da = jnp.concatenate([lay.get(theta, "da"), jnp.zeros(1)])
    db = jnp.concatenate([lay.get(theta, "db"), jnp.zeros(1)])
    return a, a[:, None] + da[:, None] * s, b[:, None] + db[:, None] * s


def _branches(lay: Layout, theta, ints, consts, v):
    """Time index, change indicator ``s(t)``, branch regressors and the extended branches
    ``P1``, ``P2`` at every sample (the band is ``L = min``, ``H = max`` of them)."""
    g = lambda name: lay.get(theta, name)  # noqa: E731
    t = jnp.arange(v.shape[0])
    s = (t >= ints[1]).astype(v.dtype)
    powers = power_columns(v, lay.m)
    extra = (v / consts[0]) ** lay.m
    _, _, c1, c2 = lay.base(theta)
    p1 = powers @ c1 + s * (powers @ g("dc1")) + g("c1_extra")[0] * extra
    p2 = powers @ c2 + s * (powers @ g("dc2")) + g("c2_extra")[0] * extra
    return t, s, powers, extra, p1, p2


def _gather(p1, p2, u0):
    """Play-operator output as a gather of branch values at primal-only indices."""
    low, high = jnp.minimum(p1, p2), jnp.maximum(p1, p2)
    _, src = play_sources(jax.lax.stop_gradient(low), jax.lax.stop_gradient(high), u0=u0)
    return gather_play(low, high, src, u0)


def play_gather(lay: Layout, theta, consts, v, u0=0.0):
    """Backlash output of the base branches in ``theta`` (no change, no extra degree
    term unless set), differentiable in the branch coefficients."""
    ints = jnp.asarray([0, 2**30])
    _, _, _, _, p1, p2 = _branches(lay, theta, ints, consts, v)
    return _gather(p1, p2, u0)


def fast_prediction_error(lay: Layout, theta, ints, consts, v, y, u0=0.0,
                          output_static: bool = True, criterion: str = "prediction"):
    """Prediction error of the extended model for fitting (see the comment above);
    equals ``prediction_error(...)[0]`` for any single extension, up to the start-up
    transient. ``output_static=False`` drops the output clip and curvature (and the FFT
    they need) for candidates that keep them neutral. ``criterion="simulation"`` returns
    the output error ``y - y_sim = w / A`` instead (no noise model)."""
    g = lambda name: lay.get(theta, name)  # noqa: E731
    t, s, powers, extra, p1, p2 = _branches(lay, theta, ints, consts, v)
    u = jnp.clip(_gather(p1, p2, u0), g("in_lo")[0], g("in_hi")[0])
    d = ints[0]
    u = jnp.where(t >= d, u[jnp.maximum(t - d, 0)], 0.0)
    a, a_t, b_t = linear_block(lay, theta, s)
    du = u - jnp.concatenate([u[:1], u[:-1]])
    tf = t.astype(v.dtype)
    phase = 2 * math.pi * g("sin_freq")[0] * tf
    add = (drift(lay, theta, tf)[0] + g("sin_cos")[0] * jnp.cos(phase)
           + g("sin_sin")[0] * jnp.sin(phase) + g("friction")[0] * jnp.tanh(du / consts[3]))
    r = y - add
    if output_static:
        y_lin = iir_fft(a, lag_sum(b_t, u))
        z = (y_lin - consts[1]) / consts[2]
        shaped = y_lin + consts[2] * (g("nl2")[0] * z**2 + g("nl3")[0] * z**3) + add
        # the output error sees the clipped output; the predictor clips its prediction
        # of the unclipped model instead (clipped_error below, module docstring)
        out = output_clip(lay, theta, shaped) if criterion == "simulation" else shaped
        r = r - (out - y_lin - add)
    # the ARX equation error of eq. (10) on the extended model's signals
    w = equation_error(a_t, b_t, r, u)
    if criterion == "simulation":
        return iir_fft(a, w)
    eps = w + lag_sum(g("noise_d"), w)
    return clipped_error(lay, theta, y, eps) if output_static else eps


def fast_jacobian(lay: Layout, theta, ints, consts, v, y, u0=0.0, criterion="prediction"):
    """``d eps / d theta`` of :func:`fast_prediction_error` with ``output_static=False``,
    shape ``(T, P)``, by the chain rule written out on whole records (forward-mode
    autodiff of the same expression costs an order of magnitude more on a CPU: dozens
    of small ops per tangent). Columns of the output-static slots are zero."""
    na, nb = lay.na, lay.nb
    slots = lay.slots()
    P = lay.size
    g = lambda name: lay.get(theta, name)  # noqa: E731
    T = v.shape[0]
    t, s, powers, extra, p1, p2 = _branches(lay, theta, ints, consts, v)
    low, high = jnp.minimum(p1, p2), jnp.maximum(p1, p2)
    _, src = play_sources(low, high, u0=u0)
    kk, hi, valid = source_edges(src)
    valid = valid.astype(v.dtype)
    u_raw = gather_play(low, high, src, u0)
    # which branch the held value came from
    from1 = jnp.where(hi, p1[kk] >= p2[kk], p1[kk] <= p2[kk]).astype(v.dtype)
    w1, w2 = valid * from1, valid * (1 - from1)

    def block(name, values):
        start, stop = slots[name]
        return (start, stop, values)

    Vk, Ek, sk = powers[kk], extra[kk], s[kk]
    u_blocks = [block("c1", w1[:, None] * Vk), block("c2", w2[:, None] * Vk),
                block("dc1", (w1 * sk)[:, None] * Vk), block("dc2", (w2 * sk)[:, None] * Vk),
                block("c1_extra", (w1 * Ek)[:, None]), block("c2_extra", (w2 * Ek)[:, None])]
    Du = jnp.zeros((T, P), v.dtype)
    for start, stop, val in u_blocks:
        Du = Du.at[:, start:stop].set(val)
    in_lo, in_hi = g("in_lo")[0], g("in_hi")[0]
    below, above = u_raw < in_lo, u_raw > in_hi
    Du = Du * (~(below | above)).astype(v.dtype)[:, None]
    Du = Du.at[:, slots["in_lo"][0]].set(below.astype(v.dtype))
    Du = Du.at[:, slots["in_hi"][0]].set(above.astype(v.dtype))
    u_s = jnp.clip(u_raw, in_lo, in_hi)
    d = ints[0]
    idx = jnp.maximum(t - d, 0)
    on = (t >= d).astype(v.dtype)
    u = on * u_s[idx]
    Du = on[:, None] * Du[idx]

    a, a_t, b_t = linear_block(lay, theta, s)
    Dbu = lag_sum(b_t, Du)
    for i in range(nb):
        Dbu = Dbu.at[:, slots["b"][0] + i].add(lagged(u, i + 1))
        Dbu = Dbu.at[:, slots["db"][0] + i].add(s * lagged(u, i + 1))
    Dbu = Dbu.at[:, slots["b_extra"][0]].add(lagged(u, nb + 1))

    du = u - jnp.concatenate([u[:1], u[:-1]])
    Ddu = Du - jnp.concatenate([Du[:1], Du[:-1]])
    tf = t.astype(v.dtype)
    phase = 2 * math.pi * g("sin_freq")[0] * tf
    sc, ss, F = g("sin_cos")[0], g("sin_sin")[0], g("friction")[0]
    th = jnp.tanh(du / consts[3])
    level, d_rate, d_decay = drift(lay, theta, tf)
    add = level + sc * jnp.cos(phase) + ss * jnp.sin(phase) + F * th
    Dadd = (F * (1 - th**2) / consts[3])[:, None] * Ddu
    for name, col in (("drift_offset", jnp.ones_like(tf)), ("drift_rate", d_rate),
                      ("drift_decay", d_decay),
                      ("sin_freq", 2 * math.pi * tf * (ss * jnp.cos(phase) - sc * jnp.sin(phase))),
                      ("sin_cos", jnp.cos(phase)), ("sin_sin", jnp.sin(phase)), ("friction", th)):
        Dadd = Dadd.at[:, slots[name][0]].add(col)

    r = y - add
    w = equation_error(a_t, b_t, r, u)
    Dr = -Dadd
    Dw = Dr + lag_sum(a_t, Dr) - Dbu
    for i in range(na):
        Dw = Dw.at[:, slots["a"][0] + i].add(lagged(r, i + 1))
        Dw = Dw.at[:, slots["da"][0] + i].add(s * lagged(r, i + 1))
    Dw = Dw.at[:, slots["a_extra"][0]].add(lagged(r, na + 1))
    if criterion == "simulation":
        # e = w / A:  de = (dw - (dA) e) / A
        e = iir_fft(a, w)
        for i in range(na):
            Dw = Dw.at[:, slots["a"][0] + i].add(-lagged(e, i + 1))
        Dw = Dw.at[:, slots["a_extra"][0]].add(-lagged(e, na + 1))
        return iir_fft(a, Dw)
    De = Dw + lag_sum(g("noise_d"), Dw)
    De = De.at[:, slots["noise_d"][0]].add(lagged(w, 1))
    De = De.at[:, slots["noise_d"][0] + 1].add(lagged(w, 2))
    return De
