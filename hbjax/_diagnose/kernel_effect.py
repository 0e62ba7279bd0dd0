"""Effects that are slots of the fast extended simulator (:mod:`.kernel`).

A built-in effect declares which slots of the extended parameter vector its fields are
(``slots``), which of its static fields are the kernel's discrete values (``int_fields``:
index into ``[extra delay, change time]``) or fixed scales (``const_fields``: index into
``[v_scale, y_center, y_scale, friction_width]``), and which compiled batch fits it. This
base class does the rest: the extended vector of an instance (:meth:`parts`), its
simulation and prediction through the single extended simulator, and the fitted instance
from a fitted vector (:meth:`from_fit`). A concrete effect supplies its starts
(:meth:`candidate`), its sentence (:meth:`describe`) and its concealed-recording recipe.
"""

from __future__ import annotations

import abc
import math
from typing import ClassVar

import jax.numpy as jnp
import numpy as np

from .._core.model import Hammerstein
from .effect_base import AbstractEffect, Candidate, Context, base_model, neutral_ints
from .kernel import Layout, simulate_full, whiten

#: slots holding vectors (the others hold one number)
VECTOR_SLOTS = ("a", "b", "c1", "c2", "da", "db", "dc1", "dc2", "noise_d")
#: clip levels: an infinite level is a side that is not clipped (``None`` in the model)
LEVEL_SLOTS = ("in_lo", "in_hi", "out_lo", "out_hi")
#: neutral fixed scales ``[v_scale, y_center, y_scale, friction_width]``
NEUTRAL_CONSTS = (1.0, 0.0, 1.0, 1.0)


def layout_of(base: Hammerstein) -> Layout:
    return Layout.of(base)


def base_theta(base: Hammerstein):
    """``(layout, theta)`` of the nominal model with every extension switched off."""
    lay = Layout.of(base)
    return lay, lay.neutral(base)


class AbstractKernelEffect(AbstractEffect):
    """An effect expressed by slots of the extended simulator (see the module docstring).

    Class variables: ``slots`` (field -> kernel slot), ``int_fields`` (field -> index into
    ``ints``), ``const_fields`` (field -> index into ``consts``), ``output_static``
    (fitted in the batch with the output clip/curvature, which needs the FFT and a
    forward-mode Jacobian) and ``wide`` (frees a second copy of the base parameters).
    """

    slots: ClassVar[dict] = {}
    int_fields: ClassVar[dict] = {}
    const_fields: ClassVar[dict] = {}
    output_static: ClassVar[bool] = False
    wide: ClassVar[bool] = False

    def parts(self):
        """``(layout, theta, ints, consts)`` of this model in the extended simulator."""
        lay, theta = base_theta(self.base)
        for field, slot in self.slots.items():
            value = getattr(self, field)
            if value is not None:
                theta = lay.put(theta, slot, value)
        ints = [int(x) for x in neutral_ints()]
        for field, k in self.int_fields.items():
            ints[k] = getattr(self, field)
        consts = list(NEUTRAL_CONSTS)
        for field, k in self.const_fields.items():
            consts[k] = getattr(self, field)
        return (lay, theta, jnp.asarray(ints, dtype=jnp.int32),
                jnp.asarray(consts, dtype=jnp.float64))

    def simulate_trajectory(self, v, noise, u0):
        lay, theta, ints, consts = self.parts()
        return simulate_full(lay, theta, ints, consts, v, noise, u0)[0]

    def predict_trajectory(self, v, y, u0):
        lay, theta, ints, consts = self.parts()
        y_pre = simulate_full(lay, theta, ints, consts, v, jnp.zeros_like(v), u0, clip=False)[0]
        return y - whiten(lay, theta, ints, y, y_pre)

    @classmethod
    @abc.abstractmethod
    def candidate(cls, ctx: Context) -> Candidate:
        """Starts ``(theta0, ints)`` from the residual signatures and the freed slots."""

    @classmethod
    def from_fit(cls, ctx: Context, theta, ints, params=None):
        lay = ctx.lay
        values = {}
        for field, slot in cls.slots.items():
            val = lay.get(theta, slot)
            if slot in VECTOR_SLOTS:
                values[field] = jnp.asarray(val)
            elif slot in LEVEL_SLOTS:
                x = float(val[0])
                values[field] = jnp.asarray(x) if math.isfinite(x) else None
            else:
                values[field] = jnp.asarray(val[0])
        for field, k in cls.int_fields.items():
            values[field] = int(ints[k])
        for field, k in cls.const_fields.items():
            values[field] = float(ctx.consts[k])
        return cls(base=base_model(lay, theta), **values)

    @classmethod
    def nominal_candidate(cls, ctx: Context, free=(), *, starts=None, grid: int = 1,
                          levels=()) -> Candidate:
        """A candidate started at the nominal model (or at ``starts``) freeing ``free``."""
        if starts is None:
            starts = [(ctx.theta_nom, neutral_ints())]
        return Candidate(cls, starts, list(free), grid=grid, levels=tuple(levels))


def put(ctx: Context, **values):
    """The nominal vector with some slots set."""
    theta = ctx.theta_nom
    for name, val in values.items():
        theta = ctx.lay.put(theta, name, val)
    return theta


def signals(v, y0, u, n) -> dict:
    """What a concealed-recording recipe sees: input, clean output, internal signal."""
    return {"v": np.asarray(v), "y0": np.asarray(y0), "u": np.asarray(u), "n": int(n),
            "sy": float(np.std(y0))}
