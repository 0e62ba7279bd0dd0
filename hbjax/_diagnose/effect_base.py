"""The base class of the diagnosis's physics library: one effect is one class.

An effect is a final :class:`hbjax.AbstractModel` wrapping the nominal model (``base``) with
one mechanism the paper's model (eq. (10)) leaves out. The class holds everything about
it: its fitted parameters (fields), how it enters the model (``simulate``/``predict``), its
signature-driven start values (:meth:`AbstractEffect.candidate`), how a fitted vector
becomes an instance (:meth:`AbstractEffect.from_fit`), its physics sentence
(:meth:`AbstractEffect.describe`) and its parameter table. :data:`hbjax.EFFECTS` is built
from the classes.

Two paths share this base, as diffrax's Runge-Kutta solvers share ``AbstractRungeKutta``:

- the built-in effects are slots of the fast extended simulator (:mod:`.kernel`), fitted
  with a hand-written Jacobian (:class:`.kernel_effect.AbstractKernelEffect`);
- any other effect uses the generic path defined here: it adds ``output_term`` (after the
  linear block) and/or ``input_term`` (between the backlash and the linear block) with
  ``n_params`` parameters started at ``start(ctx)``, and is fitted jointly with the base
  parameters by the same Levenberg-Marquardt solver with a ``jax.jacfwd`` Jacobian.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._core import display
from .._core.arx import ARX, all_pole, equation_error
from .._core.model import AbstractModel, Hammerstein, play_trajectory
from .._misc import as_float_array, is_traced, lag_sum, positive_int
from .kernel import Layout, iir_fft, play_gather


@dataclasses.dataclass
class Context:
    """What an effect's start values are built from: the fitting segment and the nominal
    model's behaviour on it (``*_nom`` arrays are over the fitting segment).

    ``lay``/``theta_nom``: the nominal model in the extended parameter vector;
    ``consts``: the fixed scales ``[v_scale, y_center, y_scale, friction_width]``;
    ``v_fit``, ``y_fit``: the fitting segment; ``y_sim_nom``: the nominal free run;
    ``u_nom``: the nominal internal signal; ``eps_nom``: the nominal prediction error;
    ``burn``: samples left out of the criterion; ``change_scan``: the change-point scan.
    """

    lay: Layout
    theta_nom: jnp.ndarray
    consts: jnp.ndarray
    v_fit: np.ndarray
    y_fit: np.ndarray
    y_sim_nom: np.ndarray
    u_nom: np.ndarray
    eps_nom: np.ndarray
    burn: int
    change_scan: dict
    #: the whole record's input (fitting and held-out parts): the inputs a refitted branch
    #: must hold at (:func:`hbjax._diagnose.candidates.branch_directions`)
    v_record: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.y_fit)


@dataclasses.dataclass
class Candidate:
    """One effect to fit: its class, the possible starts ``(theta0, ints)`` (the best is
    chosen by a batched evaluation of the criterion), the kernel slots it frees with a
    scale each (``levels``: slots freed only where the start is finite, e.g. a clip level
    that may stay open), the size ``grid`` of the discrete search behind the start
    (penalised in the BIC) and, for the generic path, the parameter starts ``params``
    (rows) and their scales; after the fit ``params`` holds the fitted parameters.
    ``anchored``: the base parameters stay at the nominal values (only the effect's own
    parameters are fitted)."""

    cls: type
    starts: list
    free: list = dataclasses.field(default_factory=list)
    grid: int = 1
    levels: tuple = ()
    params: np.ndarray | None = None
    scales: np.ndarray | None = None
    anchored: bool = False
    #: the fitted directions of the branch slots (``{"c1": D, ...}``, ``D`` of shape
    #: ``(m, r)``; a slot not named is fitted in full): ``candidates.branch_directions``
    directions: dict | None = None

    @property
    def effect(self) -> str:
        return self.cls.name

    @property
    def label(self) -> str:
        """The effect's name; for the anchored variant (base parameters held at the
        nominal values, only the effect's own parameters fitted) with ``ANCHORED``."""
        return self.effect + ANCHORED if self.anchored else self.effect

    @property
    def generic(self) -> bool:
        return self.params is not None


#: suffix of an anchored candidate's label (its rows in ``Diagnosis.candidates``)
ANCHORED = " (nominal base)"

NO_CHANGE = 2**30  # change time "after the end of any record"


def python_int(x):
    """A NumPy integer as a Python ``int`` (a static field of an effect: equinox warns of,
    and hashes by identity, an array set as static); anything else as given, for the
    field's constraint to check (``2.5`` is refused there, not rounded here)."""
    return int(x) if isinstance(x, np.integer) else x


def neutral_ints(delay=0, time=NO_CHANGE):
    """The kernel's discrete values ``[extra delay, change time]``."""
    return np.array([delay, time], dtype=np.int32)


def base_model(lay: Layout, theta) -> Hammerstein:
    """The base :class:`hbjax.Hammerstein` in an extended parameter vector."""
    return lay.model(jnp.asarray(theta))


@dataclasses.dataclass(frozen=True)
class EffectConstraint:
    """What one parameter field of an effect must hold: declared in the class's
    ``constraints`` (field -> constraint) and checked by
    :meth:`AbstractEffect.__check_init__`, so both the constructor and
    :func:`hbjax.load_model` (which runs ``__check_init__``) refuse an invalid value with a
    ``TypeError``/``ValueError`` naming the class and the field.

    - `shape`: the array's shape, ``()`` a scalar; an entry ``"na"``, ``"nb"`` or ``"m"``
      is the base's order (the length of ``a``, of ``b``, of a backlash branch);
    - `integer`: a non-negative Python integer (a static count of samples such as a
      delay) instead of an array;
    - `finite`: no NaN or inf (default);
    - `positive`: every value > 0 (a width, a scale it divides by);
    - `minimum`, `maximum`: inclusive bounds;
    - `optional`: ``None`` is allowed (a clip side that is open);
    - `below`: another declared field this one must be strictly below where both are
      given (a clip's ``lower`` below its ``upper``).

    Traced values (the diagnosis builds effects inside ``jit``, ``vmap`` and ``grad``)
    have their type and shape checked; their values are unknown at trace time and pass.
    """

    shape: tuple = ()
    integer: bool = False
    finite: bool = True
    positive: bool = False
    minimum: float | None = None
    maximum: float | None = None
    optional: bool = False
    below: str | None = None

    def check(self, name: str, value, base: Hammerstein):
        """The concrete ``value`` of field ``name`` (``"Class.field"``) as a NumPy array,
        ``None`` where it is absent or traced; raises where it breaks the constraint."""
        if value is None:
            if self.optional:
                return None
            raise TypeError(f"`{name}` must be given, got None.")
        if self.integer:
            if is_traced(value):
                return None
            # (a Python integer of any size: compared as one, never converted to float)
            arr = np.asarray(positive_int(value, name, minimum=0), dtype=object)
        else:
            # a boolean converts to 0/1 but is no parameter value (a slip in a file)
            if isinstance(value, (bool, np.bool_)) or getattr(value, "dtype", None) == bool:
                raise TypeError(f"`{name}` must be numeric, got a boolean.")
            # type and shape are known at trace time too (as for the core blocks)
            arr = as_float_array(value, name, host=True)
            orders = {"na": base.arx.na, "nb": base.arx.nb, "m": base.backlash.m}
            shape = tuple(orders.get(s, s) for s in self.shape)
            if tuple(arr.shape) != shape:
                what = "be a scalar" if shape == () else f"have shape {shape}"
                raise ValueError(f"`{name}` must {what}, got shape {tuple(arr.shape)}.")
            if is_traced(arr):
                return None
            arr = np.asarray(arr)
            if self.finite and not np.all(np.isfinite(arr)):
                either = " or None" if self.optional else ""
                raise ValueError(f"`{name}` must be finite{either}, got {_shown(arr)}.")
        if self.positive and not np.all(arr > 0):
            raise ValueError(f"`{name}` must be > 0, got {_shown(arr)}.")
        if self.minimum is not None or self.maximum is not None:
            lo = (0 if self.integer else -np.inf) if self.minimum is None else self.minimum
            hi = np.inf if self.maximum is None else self.maximum
            if not np.all((arr >= lo) & (arr <= hi)):
                raise ValueError(f"`{name}` must be in [{lo}, {hi}], got {_shown(arr)}.")
        return arr


def _shown(arr) -> str:
    return str(arr.item()) if arr.ndim == 0 else np.array2string(arr, threshold=8)


class AbstractEffect(AbstractModel):
    """One physical mechanism the nominal HB-Hammerstein model (eq. (10)) leaves out, as a
    model: ``base`` (the nominal :class:`hbjax.Hammerstein`) plus the effect's fitted
    parameters (its other fields). :func:`hbjax.simulate` and :func:`hbjax.predict` run
    it; :func:`hbjax.diagnose` fits it (``effects=[..., MyEffect]`` or by ``name`` from
    :data:`hbjax.EFFECTS`) and reports it with :meth:`describe`.

    **To add an effect**, subclass and give:

    - `name` (``ClassVar[str]``): the effect's name in reports;
    - the fields: ``base: hbjax.Hammerstein`` first, then the parameters;
    - `n_params` (``ClassVar[int]``) and :meth:`start` (their start values from the
      diagnosis context: signatures in the nominal residual);
    - :meth:`output_term` (added to the linear block's output) and/or :meth:`input_term`
      (added to the backlash output before the linear block);
    - :meth:`describe`: the physics sentence built from the fitted values;
    - optionally `constraints` (``ClassVar[dict[str, EffectConstraint]]``): what each parameter
      field must hold (shape, finite, positive, bounds, ``None`` allowed, ordered pairs),
      checked when the effect is built or loaded from a file (:class:`hbjax.EffectConstraint`);
    - optionally `noise_rival` (``ClassVar[str]``, see below);
    - optionally `anchorable` (``ClassVar[bool]``, default ``True``): the diagnosis also
      fits the effect with the base held at the nominal values (its *anchored* variant,
      ``docs/diagnosis.md``); ``False`` for a class that is itself a change of the base;
    - optionally `anchored_form` (``ClassVar[type]``): another effect class (same `name`,
      not in :data:`hbjax.EFFECTS`) fitted as the anchored variant, where the class's own
      parametrisation needs the base to move to express the mechanism;
    - optionally `signature_rivals` (``ClassVar[tuple[str, ...]]``): effects that can mimic
      this one's residual but cannot produce a signature the recording itself shows; where
      :meth:`describe` finds that signature (``evidence["record_signature"]``), the finding
      ranks above those rivals (:func:`hbjax._diagnose.decide.rank`).

    A mechanism is reported where it improves the held-out free run
    (:func:`hbjax._diagnose.decide.decide`). `noise_rival` names a noise model that gains
    in one-step prediction exactly as the mechanism can; where the free-run gain is not
    significant, the mechanism is still reported, on its held-out prediction gain, if it
    beats that noise model by the BIC margin (so the gain is in the input-to-output
    dynamics, which the noise model cannot change).

    The context ``ctx`` the class methods receive describes the fitting segment:
    ``ctx.v_fit``, ``ctx.y_fit`` (the recording), ``ctx.y_sim_nom`` (the nominal free run),
    ``ctx.u_nom`` (the nominal backlash output), ``ctx.eps_nom`` (the nominal prediction
    error), ``ctx.burn`` (start-up samples left out of the criterion), ``ctx.n`` and
    ``ctx.change_scan`` (the change-point scan of the residual tests).

    The generic path needs nothing else: the diagnosis fits the parameters jointly with
    the base parameters (Levenberg-Marquardt, ``jax.jacfwd`` Jacobian) on the same
    criterion as every other effect. Parameters are the fields after ``base``, scalars in
    order; other shapes give :meth:`from_params` and :meth:`params` too.

    The one-step predictor is that of every extension, ``y_hat = y - A (y - y_sim)``
    (for the nominal model exactly the ARX predictor of eq. (10); the output clip acts on
    the prediction instead: ``clip(y - A (y - y_pre))``, ``y_pre`` the unclipped free run).
    """

    base: eqx.AbstractVar[Hammerstein]
    name: ClassVar[str]
    n_params: ClassVar[int] = 0
    noise_rival: ClassVar[str | None] = None
    anchorable: ClassVar[bool] = True
    anchored_form: ClassVar[type | None] = None
    signature_rivals: ClassVar[tuple[str, ...]] = ()
    constraints: ClassVar[dict[str, EffectConstraint]] = {}

    def __check_init__(self):
        if not isinstance(self.base, Hammerstein):
            raise TypeError(f"`base` must be an hbjax.Hammerstein, got {type(self.base).__name__}.")
        # The class's declared constraints: one check for every effect (the model-file
        # reader runs this too, so a loaded file is held to the constructor's rules).
        cls = type(self).__name__
        values = {field: rule.check(f"{cls}.{field}", getattr(self, field), self.base)
                  for field, rule in self.constraints.items()}
        for field, rule in self.constraints.items():
            low, high = values[field], values.get(rule.below)
            if low is not None and high is not None and not np.all(low < high):
                raise ValueError(f"`{cls}.{field}` ({_shown(low)}) must be below "
                                 f"`{cls}.{rule.below}` ({_shown(high)}).")

    # --- how it enters the model (generic path) ------------------------------------

    def input_term(self, v, u):
        """Added to the backlash output ``u`` before the linear block (default: none)."""
        return jnp.zeros_like(u)

    def output_term(self, v, u, y_lin):
        """Added to the linear block's output ``y_lin`` (default: none)."""
        return jnp.zeros_like(y_lin)

    def _signals(self, v, noise, u0):
        u = play_trajectory(self.base.backlash, v, u0)
        u = u + self.input_term(v, u)
        y_lin = _arx_filter(self.base.arx, u, noise)
        return y_lin + self.output_term(v, u, y_lin)

    def simulate_trajectory(self, v, noise, u0):
        return self._signals(v, noise, u0)

    def predict_trajectory(self, v, y, u0):
        e = y - self._signals(v, jnp.zeros_like(v), u0)
        return y - (e + lag_sum(self.base.arx.a, e))

    # --- what the diagnosis needs ----------------------------------------------------

    @classmethod
    def start(cls, ctx: Context):
        """Start values of the parameters, shape ``(n_params,)`` or several starts
        ``(n_starts, n_params)`` (the best is kept). Default: zeros."""
        return np.zeros(cls.n_params)

    @classmethod
    def scales(cls, ctx: Context):
        """Typical size of each parameter (the solver's step scale). Default: ones."""
        return np.ones(cls.n_params)

    @classmethod
    def from_params(cls, base: Hammerstein, params):
        """The effect with parameters ``params`` (default: the scalar fields after
        ``base``, in order)."""
        return cls(base, *(params[i] for i in range(cls.n_params)))

    def params(self):
        """The parameter vector :meth:`from_params` reads."""
        return jnp.stack([jnp.asarray(v) for _, v in self.fitted_values()])

    @classmethod
    def candidate(cls, ctx: Context) -> Candidate:
        """The candidate the diagnosis fits: the nominal base and the effect's starts."""
        starts = np.atleast_2d(np.asarray(cls.start(ctx), dtype=np.float64))
        if starts.shape[1] != cls.n_params:
            raise ValueError(f"{cls.__name__}.start gave {starts.shape[1]} values; "
                             f"n_params = {cls.n_params}.")
        scales = np.broadcast_to(np.asarray(cls.scales(ctx), np.float64), (cls.n_params,))
        return Candidate(cls, [(ctx.theta_nom, neutral_ints())], params=starts, scales=scales)

    @classmethod
    def from_fit(cls, ctx: Context, theta, ints, params=None):
        """The fitted effect from the fitted extended vector ``theta`` (base slots),
        discrete values ``ints`` and, on the generic path, its fitted ``params``."""
        return cls.from_params(base_model(ctx.lay, theta), jnp.asarray(params))

    @abc.abstractmethod
    def describe(self, ctx: Context, info: dict) -> dict:
        """The report of the fitted effect: ``{"physics": sentence, "where": {...},
        "parameters": {...}}`` and optionally ``"evidence"``. The sentence is built from
        the fitted values and the evidence in ``info`` (``y``, ``v``, ``n_fit``, ``ysim``
        the effect's free run, ``ysim_ref`` the refit's, ``u``, ``ints``, ``tests``)."""

    @classmethod
    def concealed(cls, base: Hammerstein, signals: dict, rng):
        """``(true model, nominal model, truth)`` hiding this effect in a simulation of
        ``base`` (for :func:`hbjax.concealed_recording`; built-in effects only)."""
        raise NotImplementedError(f"{cls.__name__} has no concealed-recording recipe.")

    def fitted_values(self) -> list[tuple[str, object]]:
        """``(field, value)`` of the effect's own parameters (fields after ``base``
        that hold numbers; ``None`` = not present)."""
        out = []
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "base" or value is None or isinstance(value, eqx.Module):
                continue
            out.append((f.name, value))
        return out

    def parameter_table(self) -> display.Table:
        """The effect's own parameters (base parameters excluded) as a table."""
        names, values = [], []
        for field, value in self.fitted_values():
            arr = np.ravel(np.asarray(value, dtype=np.float64))
            names += [field] if arr.size == 1 else [f"{field}[{i}]" for i in range(arr.size)]
            values.append(arr)
        est = np.concatenate(values) if values else np.zeros(0)
        return display.parameter_table(names, est, title=f"{type(self).__name__} ({self.name})")


def _arx_filter(arx: ARX, u, xi):
    """``A y = B u + xi`` with zero initial conditions (no feed-through: ``B`` starts at
    ``q^-1``)."""
    return all_pole(arx.a, lag_sum(arx.b, u) + xi)


def term_error(cls, lay: Layout, theta, params, consts, v, y, criterion="prediction", u0=0.0):
    """Fitting criterion of a generic effect: the prediction error ``A (y - y_sim)``
    (``criterion="simulation"``: the output error ``y - y_sim``) of ``cls`` with base
    ``theta`` and ``params``, differentiable in both (the backlash output is a gather of
    branch values, ``y_lin = (B / A) u`` by FFT, as in the fast kernel). An effect class
    that acts inside the recursion gives its own criterion as a classmethod
    ``fit_error(lay, theta, params, consts, v, y, criterion, u0)``."""
    own = getattr(cls, "fit_error", None)
    if own is not None:
        return own(lay, theta, params, consts, v, y, criterion, u0)
    return effect_error(cls.from_params(base_model(lay, theta), params), lay, theta, consts,
                        v, y, criterion, u0)


def effect_error(effect, lay: Layout, theta, consts, v, y, criterion="prediction", u0=0.0):
    """:func:`term_error` of an effect instance (its base is ``theta``)."""
    a, b, _, _ = lay.base(theta)
    u = play_gather(lay, theta, consts, v, u0)
    u = u + effect.input_term(v, u)
    y_lin = iir_fft(a, lag_sum(b, u))
    r = y - effect.output_term(v, u, y_lin)
    if criterion == "simulation":
        return r - y_lin
    return equation_error(a, b, r, u)  # eq. (10)'s equation error of the effect's signals
