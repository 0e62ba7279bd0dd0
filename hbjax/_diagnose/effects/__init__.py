"""The physics library of the diagnosis: one final class per effect (family modules
``saturation``, ``dynamics``, ``disturbances``, ``nonlinearity``), all subclasses of
:class:`hbjax.AbstractEffect`. :data:`EFFECTS` is built from the classes."""

from __future__ import annotations

from ..effect_base import NO_CHANGE as NO_CHANGE
from ..effect_base import AbstractEffect
from ..kernel_effect import base_theta as base_theta
from ..kernel_effect import layout_of as layout_of
from .disturbances import (
    ColoredNoise as ColoredNoise,
)
from .disturbances import (
    OffsetDrift as OffsetDrift,
)
from .disturbances import (
    PeriodicDisturbance as PeriodicDisturbance,
)
from .dynamics import (
    ExtraDelay as ExtraDelay,
)
from .dynamics import (
    ParameterChange as ParameterChange,
)
from .dynamics import (
    ParameterMismatch as ParameterMismatch,
)
from .dynamics import (
    UnmodeledDynamics as UnmodeledDynamics,
)
from .friction import CoulombFrictionInLoop as CoulombFrictionInLoop
from .harmonic import HarmonicDistortion as HarmonicDistortion
from .level import LevelDependentDynamics as LevelDependentDynamics
from .nonlinearity import (
    BranchDegree as BranchDegree,
)
from .nonlinearity import (
    CoulombFriction as CoulombFriction,
)
from .nonlinearity import (
    OutputNonlinearity as OutputNonlinearity,
)
from .saturation import InputSaturation as InputSaturation
from .saturation import OutputSaturation as OutputSaturation

_CLASSES = (
    ParameterMismatch, OutputSaturation, InputSaturation, ExtraDelay, UnmodeledDynamics,
    ColoredNoise, OffsetDrift, ParameterChange, PeriodicDisturbance, OutputNonlinearity,
    CoulombFrictionInLoop, BranchDegree, LevelDependentDynamics, HarmonicDistortion,
)

#: effect name -> the :class:`hbjax.AbstractEffect` subclass that expresses it (built from
#: the classes' ``name``). ``parameter_mismatch`` is the refit of the nominal structure,
#: the reference every structural effect must beat.
EFFECTS = {cls.name: cls for cls in _CLASSES}


def resolve(effects) -> list[type]:
    """Effect classes from ``effects``: names from :data:`EFFECTS` and/or
    :class:`hbjax.AbstractEffect` subclasses; ``None`` is every built-in effect.
    ``parameter_mismatch`` (the reference) is always first."""
    if effects is None:
        return list(EFFECTS.values())
    if isinstance(effects, (str, type)):
        effects = [effects]
    if not isinstance(effects, (list, tuple, set, frozenset)):
        raise TypeError(f"`effects` must be a list of names from hbjax.EFFECTS or "
                        f"hbjax.AbstractEffect subclasses, got {type(effects).__name__}.")
    effects = list(effects)
    unknown = [e for e in effects if not (isinstance(e, str) and e in EFFECTS)
               and not (isinstance(e, type) and issubclass(e, AbstractEffect))]
    if unknown:
        raise ValueError(f"unknown effect name(s) in `effects`: {unknown}; "
                         f"known: {sorted(EFFECTS)} (or an hbjax.AbstractEffect subclass).")
    classes = []
    for e in effects:
        cls = EFFECTS[e] if isinstance(e, str) else e
        if getattr(cls, "__abstractmethods__", None):
            raise TypeError(f"effect class {cls.__name__} is abstract: it does not implement "
                            f"{sorted(cls.__abstractmethods__)}.")
        if not isinstance(getattr(cls, "name", None), str):
            raise TypeError(f"effect class {cls.__name__} needs a `name: ClassVar[str]`.")
        if cls not in classes:
            classes.append(cls)
    names = [c.name for c in classes]
    clash = sorted({n for n in names if names.count(n) > 1})
    if clash:
        raise ValueError(f"two effect classes share the name(s) {clash} in `effects`.")
    if ParameterMismatch not in classes:
        classes.insert(0, ParameterMismatch)
    return classes
