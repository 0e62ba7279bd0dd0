"""Bad input at every public entry point: a clear error naming the argument, never a silent
NaN or a wrong-shape result (issue 7).

Three tables drive the tests:

- ``CASES``: refused inputs, each with the exception type and a message fragment;
- ``PROMOTED``: accepted inputs (integer, float32, bool, lists) that must give exactly the
  float64 result;
- ``TRACED``: value checks that run inside ``jax.jit``/``jax.vmap`` (``eqx.error_if``) and
  whose message must survive both.

``tests/README.md`` lists the classes and the number of cases of each; regenerate it with
``python tests/test_robustness.py`` (``test_readme_counts_are_current`` fails when stale).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import io
import pathlib
import re
import sys
from collections import Counter
from typing import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import hbjax
from hbjax._cli.parser import main as cli_main
from hbjax import ModelFileError

# ----------------------------------------------------------------------------- fixtures
# Module-level, built lazily: table entries are lambdas ``call(tmp)`` with ``tmp`` a fresh
# temporary folder (pathlib.Path).

M = hbjax.default_system()
D = hbjax.default_design()
BL, ARX = M.backlash, M.arx
H_M = D.h_m
V = D.staircase_input(60)
Y = np.linspace(-1.0, 1.0, 60)
THETA = np.asarray(hbjax.flatten_params(M))
T_GIRI = 400


@functools.cache
def records(which: str = "default", T: int = T_GIRI, noise_std: float = 0.0):
    """Outputs ``(y1, y2, y3)`` of the paper's three experiments for a few systems."""
    model = {
        "default": M,
        "zero_gain": hbjax.Hammerstein(BL, hbjax.ARX([-1.2, 0.5], [1.0, -1.0])),
        "unstable": hbjax.Hammerstein(BL, hbjax.ARX([-1.5, 0.2], [1.0, 0.5])),
    }[which]
    rng = np.random.default_rng(7)
    return tuple(
        np.asarray(hbjax.simulate(model, v, noise_std * rng.standard_normal(T)))
        for v in (D.constant_input(T), D.binary_input(T), D.staircase_input(T))
    )


def model_with(a=None, b=None, c1=None, c2=None):
    return hbjax.Hammerstein(
        hbjax.Backlash(BL.c1 if c1 is None else c1, BL.c2 if c2 is None else c2),
        hbjax.ARX(ARX.a if a is None else a, ARX.b if b is None else b),
    )


UNSTABLE = model_with(a=[-1.5, 0.2])
ZERO_GAIN = model_with(b=[1.0, -1.0])
CROSSING = model_with(c1=[-1.0, 0.9, 0.2])  # P1 - P2 changes sign at v = +-3.09
MU_ZERO = hbjax.Hammerstein(hbjax.Backlash([0.0, 1.0], [0.0, -1.0]), hbjax.ARX([-0.5], [1.0]))
# P1 = v^2, P2 = 1: mu = 1 - h_m^2 vanishes at h_m = 1 only.
MU_ZERO_AT_1 = hbjax.Hammerstein(hbjax.Backlash([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]), hbjax.ARX([-0.5], [1.0]))


def with_nan(x, i=3, value=np.nan):
    x = np.array(x, dtype=float)
    x[i] = value
    return x


def model_file(tmp) -> pathlib.Path:
    p = tmp / "model.json"
    if not p.exists():
        hbjax.save_model(p, M)
    return p


def _an_axes():
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    plt.close(fig)
    return ax


def text_file(tmp, name, text) -> pathlib.Path:
    p = tmp / name
    p.write_text(text)
    return p


class CLIError(Exception):
    """A CLI run that exited non-zero; the message is ``exit <status>: <stderr>``."""


def cli(*argv):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            status = cli_main([str(a) for a in argv])
        except SystemExit as exc:  # argparse usage errors
            status = exc.code
    if status != 0:
        raise CLIError(f"exit {status}: {err.getvalue().strip()}")
    return status


# ----------------------------------------------------------------------------- the tables


@dataclasses.dataclass(frozen=True)
class Case:
    kind: str  # bad-input class (a row of tests/README.md)
    target: str  # the public function or class
    call: Callable  # call(tmp) -> must raise
    exc: type
    match: str  # regular expression searched in the message
    xfail: str | None = None  # a known gap in another module, reported for fixing


CASES: list[Case] = []


def bad(kind, target, exc, match, call, xfail=None):
    CASES.append(Case(kind, target, call, exc, match, xfail))


WRONG_TYPE = "wrong type (not a model/design/recording, strings)"
RANK = "wrong rank or shape"
LENGTH = "length mismatch"
EMPTY = "empty array"
NONFINITE = "NaN or inf"
MAGNITUDE = "samples whose squares overflow or underflow float64 (beyond 1e100, below 1e-100)"
DTYPE = "refused dtype (complex, object, text)"
ORDER = "non-integer or negative order / count"
H_M_BAD = "h_m <= 0 or not a number"
COEF = "coefficient array of the wrong length / orders"
V2 = "input record not the design's signal (v2 not in {-h_m, +h_m})"
SHORT = "record shorter than one period"
GAIN = "B*(1) = 0 (assumption A5)"
MU = "mu = 0 / swing does not cross the gap (A4)"
UNSTABLE_A = "unstable A (assumption A3)"
CROSS = "branches cross inside the excited range"
KEY = "wrong key type"
OPTION = "unknown option or name"
IDENT = "records that do not identify the parameters"
FILES = "files: missing, corrupted, existing, bad folder"
HOSTILE = "files: hostile or loose content (huge numbers, deep nesting, 1_000, degree cap)"
OUTPUTS = "outputs: special files, '-', clashes, checked before any work"
CLI = "command line"
RANGE = "interval or window out of order or beyond the record; sampling period <= 0"

# --- wrong types
bad(WRONG_TYPE, "simulate", TypeError, "`model` must be an hbjax.AbstractModel", lambda t: hbjax.simulate(BL, V))
bad(WRONG_TYPE, "simulate", TypeError, "`model` must be an hbjax.AbstractModel", lambda t: hbjax.simulate(None, V))
bad(WRONG_TYPE, "simulate", TypeError, "`v` must be a numeric array", lambda t: hbjax.simulate(M, "0.5, 1.0"))
bad(WRONG_TYPE, "simulate", TypeError, "`noise` must be a numeric array", lambda t: hbjax.simulate(M, V, "xi"))
bad(WRONG_TYPE, "simulate", TypeError, "`u0` must be a numeric array", lambda t: hbjax.simulate(M, V, u0=None))
bad(WRONG_TYPE, "play", TypeError, "`backlash` must be an hbjax.Backlash", lambda t: hbjax.play(M, V))
bad(WRONG_TYPE, "predict", TypeError, "`model` must be an hbjax.AbstractModel", lambda t: hbjax.predict("model", V, Y))
bad(WRONG_TYPE, "predict", TypeError, "`y` must be a numeric array", lambda t: hbjax.predict(M, V, None))
bad(WRONG_TYPE, "Hammerstein", TypeError, "`backlash` must be an hbjax.Backlash", lambda t: hbjax.Hammerstein(ARX, BL))
bad(WRONG_TYPE, "Hammerstein", TypeError, "`arx` must be an hbjax.ARX", lambda t: hbjax.Hammerstein(BL, BL))
bad(WRONG_TYPE, "Backlash", TypeError, "`c1` must be a numeric array", lambda t: hbjax.Backlash("1 2", [1.0, 2.0]))
bad(WRONG_TYPE, "ARX", TypeError, "`b` must be a numeric array", lambda t: hbjax.ARX([0.5], None))
bad(WRONG_TYPE, "identify_giri", TypeError, "`design` must be an hbjax.GiriDesign", lambda t: hbjax.identify_giri((2, 3, 4.0), *records()))
bad(WRONG_TYPE, "normalise", TypeError, "`model` must be an hbjax.Hammerstein", lambda t: hbjax.normalise(BL, H_M))
bad(WRONG_TYPE, "normalise", TypeError, "`h_m` must be a numeric array", lambda t: hbjax.normalise(M, "4"))
bad(WRONG_TYPE, "normalise", TypeError, "`h_m` must be a real number, got True", lambda t: hbjax.normalise(M, True))
bad(WRONG_TYPE, "GiriDesign", TypeError, "`h_m` must be a real number", lambda t: hbjax.GiriDesign(2, 3, "4"))
bad(WRONG_TYPE, "GiriDesign", TypeError, "`h_m` must be a real number", lambda t: hbjax.GiriDesign(2, 3, True))
bad(WRONG_TYPE, "GiriDesign", TypeError, "`h_m` must be a real number", lambda t: hbjax.GiriDesign(2, 3, [4.0]))
bad(WRONG_TYPE, "GiriDesign.check_model", TypeError, "`model` must be an hbjax.Hammerstein", lambda t: D.check_model(ARX))
bad(WRONG_TYPE, "flatten_params", TypeError, "`model` must be an hbjax.Hammerstein", lambda t: hbjax.flatten_params(ARX))
bad(WRONG_TYPE, "unflatten_params", TypeError, "`like` must be an hbjax.Hammerstein", lambda t: hbjax.unflatten_params(BL, THETA))
bad(WRONG_TYPE, "param_names", TypeError, "`model` must be an hbjax.Hammerstein", lambda t: hbjax.param_names(None))
bad(WRONG_TYPE, "Recording", TypeError, "`v` must be a numeric array", lambda t: hbjax.Recording("abc", [1.0]))
bad(WRONG_TYPE, "Recording", TypeError, "`dt` must be a positive float", lambda t: hbjax.Recording([1.0], [1.0], dt="1"))
bad(WRONG_TYPE, "save_model", TypeError, "`model` must be an hbjax model", lambda t: hbjax.save_model(t / "m.json", BL))
bad(WRONG_TYPE, "save_recording", TypeError, "`recording` must be an hbjax.Recording", lambda t: hbjax.save_recording(t / "r.csv", (V, Y)))
bad(WRONG_TYPE, "load_recording", TypeError, "`input` must be a column name or index", lambda t: hbjax.load_recording(text_file(t, "r.csv", "v,y\n1,2\n"), input=1.5))

# --- rank / shape
bad(RANK, "simulate", ValueError, "`v` must be a 1-D array, got shape \\(60, 1\\)", lambda t: hbjax.simulate(M, V[:, None]))
bad(RANK, "simulate", ValueError, "`v` must be a 1-D array, got shape \\(\\)", lambda t: hbjax.simulate(M, 1.0))
bad(RANK, "simulate", ValueError, "`noise` must be a 1-D array", lambda t: hbjax.simulate(M, V, np.zeros((60, 2))))
bad(RANK, "simulate", ValueError, "`u0` must be a scalar", lambda t: hbjax.simulate(M, V, u0=np.zeros(2)))
bad(RANK, "simulate", ValueError, "`v` must be a numeric array of regular shape", lambda t: hbjax.simulate(M, [[1.0, 2.0], [3.0]]))
bad(RANK, "play", ValueError, "`v` must be a 1-D array", lambda t: hbjax.play(BL, np.stack([V, V])))
bad(RANK, "play", ValueError, "`u0` must be a scalar", lambda t: hbjax.play(BL, V, u0=[0.0]))
bad(RANK, "predict", ValueError, "`y` must be a 1-D array", lambda t: hbjax.predict(M, V, Y[:, None]))
bad(RANK, "Backlash", ValueError, "`c1` must be a 1-D array", lambda t: hbjax.Backlash([[1.0, 2.0]], [[1.0, 2.0]]))
bad(RANK, "Backlash", ValueError, "`c2` must be a 1-D array", lambda t: hbjax.Backlash([1.0], 2.0))
bad(RANK, "ARX", ValueError, "`a` must be a 1-D array", lambda t: hbjax.ARX([[0.5]], [1.0]))
bad(RANK, "identify_giri", ValueError, "`y1` must be a 1-D array", lambda t: hbjax.identify_giri(D, records()[0][:, None], *records()[1:]))
bad(RANK, "identify_giri", ValueError, "`v2` must be a 1-D array", lambda t: hbjax.identify_giri(D, *records(), v2=D.binary_input(T_GIRI)[None]))
bad(RANK, "normalise", ValueError, "`h_m` must be a scalar", lambda t: hbjax.normalise(M, [4.0, 5.0]))
bad(H_M_BAD, "normalise", ValueError, "overflows for `h_m` = 1e\\+200", lambda t: hbjax.normalise(M, 1e200))
bad(RANK, "unflatten_params", ValueError, "`theta` must have shape \\(10,\\)", lambda t: hbjax.unflatten_params(M, THETA[None]))
bad(RANK, "Recording", ValueError, "`v` must be a 1-D array", lambda t: hbjax.Recording(np.ones((3, 2)), np.ones((3, 2))))

# --- length mismatch
bad(LENGTH, "simulate", ValueError, "`v` has 60, `noise` has 59", lambda t: hbjax.simulate(M, V, np.zeros(59)))
bad(LENGTH, "predict", ValueError, "`v` has 60, `y` has 10", lambda t: hbjax.predict(M, V, Y[:10]))
bad(LENGTH, "identify_giri", ValueError, "`v3` is not the design's signal \\(length 399 vs 400\\)", lambda t: hbjax.identify_giri(D, *records(), v3=D.staircase_input(399)))
bad(LENGTH, "identify_giri", ValueError, "`v1` is not the design's signal", lambda t: hbjax.identify_giri(D, *records(), v1=D.constant_input(T_GIRI + 1)))
bad(LENGTH, "Recording", ValueError, "`v` and `y` must have equal lengths, got 3 and 2", lambda t: hbjax.Recording([1.0, 2.0, 3.0], [1.0, 2.0]))
bad(LENGTH, "load_recording", ValueError, "ragged row 3", lambda t: hbjax.load_recording(text_file(t, "r.csv", "v,y\n1,2\n3\n")))

# --- empty
bad(EMPTY, "simulate", ValueError, "`v` must have at least 1 samples, got 0", lambda t: hbjax.simulate(M, np.zeros(0)))
bad(EMPTY, "play", ValueError, "`v` must have at least 1 samples", lambda t: hbjax.play(BL, []))
bad(EMPTY, "predict", ValueError, "`v` must have at least 1 samples", lambda t: hbjax.predict(M, [], []))
bad(EMPTY, "Backlash", ValueError, "`c1` must hold at least one coefficient", lambda t: hbjax.Backlash([], []))
bad(EMPTY, "ARX", ValueError, "`b` must hold at least one coefficient", lambda t: hbjax.ARX([0.5], []))
bad(EMPTY, "identify_giri", ValueError, "`y1` has 0 samples", lambda t: hbjax.identify_giri(D, [], *records()[1:]))
bad(EMPTY, "load_recording", ValueError, "the file is empty", lambda t: hbjax.load_recording(text_file(t, "r.csv", "\n# only a comment\n")))
bad(EMPTY, "load_recording", ValueError, "header row but no data rows", lambda t: hbjax.load_recording(text_file(t, "r.csv", "v,y\n")))

# --- NaN / inf
bad(NONFINITE, "simulate", ValueError, "`v` contains NaN or inf \\(1 samples, first at index 3\\)", lambda t: hbjax.simulate(M, with_nan(V)))
bad(NONFINITE, "simulate", ValueError, "`noise` contains NaN or inf", lambda t: hbjax.simulate(M, V, with_nan(np.zeros(60), 59, np.inf)))
bad(NONFINITE, "simulate", ValueError, "`u0` contains NaN or inf", lambda t: hbjax.simulate(M, V, u0=np.nan))
bad(NONFINITE, "play", ValueError, "`v` contains NaN or inf", lambda t: hbjax.play(BL, with_nan(V, 0, -np.inf)))
bad(NONFINITE, "predict", ValueError, "`y` contains NaN or inf", lambda t: hbjax.predict(M, V, with_nan(Y)))
bad(NONFINITE, "Backlash", ValueError, "`c1` and `c2` must be finite", lambda t: hbjax.Backlash([np.nan, 1.0], [0.0, 1.0]))
bad(NONFINITE, "ARX", ValueError, "`a` and `b` must be finite", lambda t: hbjax.ARX([np.inf], [1.0]))
bad(NONFINITE, "identify_giri", ValueError, "`y2` contains NaN or inf", lambda t: hbjax.identify_giri(D, records()[0], with_nan(records()[1], 399), records()[2]))
bad(NONFINITE, "normalise", ValueError, "`h_m` must be > 0, got nan", lambda t: hbjax.normalise(M, np.nan))
bad(NONFINITE, "GiriDesign", ValueError, "`h_m` must be a finite number > 0, got inf", lambda t: hbjax.GiriDesign(2, 3, np.inf))
bad(NONFINITE, "unflatten_params", ValueError, "`theta` contains NaN or inf", lambda t: hbjax.unflatten_params(M, with_nan(THETA)))
bad(NONFINITE, "Recording", ValueError, "`y` contains NaN or inf \\(1 samples, first at index 1\\)", lambda t: hbjax.Recording([1.0, 2.0], [1.0, np.nan]))
bad(NONFINITE, "load_recording", ValueError, "not finite\\) at row 3", lambda t: hbjax.load_recording(text_file(t, "r.csv", "v,y\n1,2\n3,nan\n")))

# --- refused dtypes
bad(DTYPE, "simulate", TypeError, "`v` must be real, got complex", lambda t: hbjax.simulate(M, V + 1j))
bad(DTYPE, "simulate", TypeError, "`v` must be a numeric array, got dtype <U", lambda t: hbjax.simulate(M, np.array(["1", "2"])))
bad(DTYPE, "predict", TypeError, "`y` must be a numeric array, got dtype object", lambda t: hbjax.predict(M, V, np.array([None] * 60)))
bad(DTYPE, "Backlash", TypeError, "`c2` must be real", lambda t: hbjax.Backlash([1.0], [1j]))
bad(DTYPE, "identify_giri", TypeError, "`y3` must be real", lambda t: hbjax.identify_giri(D, *records()[:2], records()[2] + 0j))
bad(DTYPE, "Recording", TypeError, "`v` must be real", lambda t: hbjax.Recording([1j], [1.0]))

# --- orders and counts
bad(ORDER, "GiriDesign", ValueError, "`n` must be an integer >= 1, got 0", lambda t: hbjax.GiriDesign(0, 3, 4.0))
bad(ORDER, "GiriDesign", ValueError, "`n` must be an integer >= 1, got -1", lambda t: hbjax.GiriDesign(-1, 3, 4.0))
bad(ORDER, "GiriDesign", TypeError, "`n` must be an integer, got 2.5", lambda t: hbjax.GiriDesign(2.5, 3, 4.0))
bad(ORDER, "GiriDesign", TypeError, "`n` must be an integer, got 2.0", lambda t: hbjax.GiriDesign(2.0, 3, 4.0))
bad(ORDER, "GiriDesign", TypeError, "`n` must be an integer, got True", lambda t: hbjax.GiriDesign(True, 3, 4.0))
bad(ORDER, "GiriDesign", TypeError, "`m` must be an integer, got '3'", lambda t: hbjax.GiriDesign(2, "3", 4.0))
bad(ORDER, "GiriDesign", ValueError, "`m` must be an integer >= 1, got 0", lambda t: hbjax.GiriDesign(2, 0, 4.0))
bad(ORDER, "GiriDesign", ValueError, "`m` must be at most 64 .*got 65", lambda t: hbjax.GiriDesign(2, 65, 4.0))
bad(ORDER, "GiriDesign.constant_input", TypeError, "`T` must be an integer, got 1.5", lambda t: D.constant_input(1.5))
bad(ORDER, "GiriDesign.binary_input", ValueError, "`T` must be an integer >= 8, got -1", lambda t: D.binary_input(-1))
bad(ORDER, "GiriDesign.staircase_input", TypeError, "`T` must be an integer, got None", lambda t: D.staircase_input(None))
bad(ORDER, "GiriDesign.estimation_instants", ValueError, "`T` must be an integer >= 18, got 0", lambda t: D.estimation_instants(0))
bad(ORDER, "identify_giri", ValueError, "`transient` must be a non-negative integer, got -1", lambda t: hbjax.identify_giri(D, *records(), transient=-1))
bad(ORDER, "identify_giri", ValueError, "`transient` must be a non-negative integer, got 2.5", lambda t: hbjax.identify_giri(D, *records(), transient=2.5))
bad(ORDER, "identify_giri", ValueError, "`transient` \\(400\\) leaves no sample of `y1`", lambda t: hbjax.identify_giri(D, *records(), transient=T_GIRI))

# --- h_m
bad(H_M_BAD, "GiriDesign", ValueError, "`h_m` must be a finite number > 0, got 0", lambda t: hbjax.GiriDesign(2, 3, 0.0))
bad(H_M_BAD, "GiriDesign", ValueError, "`h_m` must be a finite number > 0, got -4", lambda t: hbjax.GiriDesign(2, 3, -4.0))
bad(H_M_BAD, "normalise", ValueError, "`h_m` must be > 0, got 0.0", lambda t: hbjax.normalise(M, 0.0))
bad(H_M_BAD, "normalise", ValueError, "`h_m` must be > 0, got -1.0", lambda t: hbjax.normalise(M, -1))

# --- coefficient lengths / orders
bad(COEF, "Backlash", ValueError, "`c1` and `c2` must have the same length m", lambda t: hbjax.Backlash([1.0, 2.0], [1.0, 2.0, 3.0]))
bad(COEF, "unflatten_params", ValueError, "`theta` must have shape \\(10,\\) for na=2, nb=2, m=3, got \\(9,\\)", lambda t: hbjax.unflatten_params(M, THETA[:9]))
bad(COEF, "GiriDesign.check_model", ValueError, "orders na=1, nb=2, m=3 but the design expects", lambda t: D.check_model(model_with(a=[0.5])))
bad(COEF, "GiriDesign.check_model", ValueError, "orders na=2, nb=2, m=2 but the design expects", lambda t: D.check_model(model_with(c1=[0.0, 1.0], c2=[1.0, 1.0])))

# --- input records that are not the design's signals
bad(V2, "identify_giri", ValueError, "`v2` must take values in \\{-h_m, \\+h_m\\}.*sample 0 is 2.0", lambda t: hbjax.identify_giri(D, *records(), v2=0.5 * D.binary_input(T_GIRI)))
bad(V2, "identify_giri", ValueError, "`v2` must take values in \\{-h_m, \\+h_m\\}.*sample 5 is 0.0", lambda t: hbjax.identify_giri(D, *records(), v2=with_nan(D.binary_input(T_GIRI), 5, 0.0)))
bad(V2, "identify_giri", ValueError, "`v2` is not the design's signal \\(first difference at sample 0\\)", lambda t: hbjax.identify_giri(D, *records(), v2=-D.binary_input(T_GIRI)))
bad(V2, "identify_giri", ValueError, "`v3` is not the design's signal", lambda t: hbjax.identify_giri(D, *records(), v3=D.staircase_input(T_GIRI)[::-1]))
bad(V2, "identify_giri", ValueError, "`v1` is not the design's signal", lambda t: hbjax.identify_giri(D, *records(), v1=np.full(T_GIRI, H_M)))
# off by 1e-9: beyond the check's tolerance (1e-12 h_m), so the first difference is found
bad(V2, "identify_giri", ValueError, "`v3` is not the design's signal \\(first difference at sample 0\\)", lambda t: hbjax.identify_giri(D, *records(), v3=D.staircase_input(T_GIRI) + 1e-9))
bad(V2, "identify_giri", ValueError, "`v1` is not the design's signal \\(first difference at sample 0\\)", lambda t: hbjax.identify_giri(D, *records(), v1=D.constant_input(T_GIRI) + 1e-9))

# --- records shorter than one period
bad(SHORT, "identify_giri", ValueError, "`y2` has 7 samples; it must cover at least one period 4n", lambda t: hbjax.identify_giri(D, records()[0], records()[1][:7], records()[2]))
bad(SHORT, "identify_giri", ValueError, "`y3` has 17 samples; it must cover at least one period 2m\\(n\\+1\\)", lambda t: hbjax.identify_giri(D, *records()[:2], records()[2][:17]))
bad(SHORT, "identify_giri", ValueError, "`y1` has 3 samples", lambda t: hbjax.identify_giri(D, records()[0][:3], *records()[1:]))
bad(SHORT, "GiriDesign.binary_input", ValueError, "`T` must be an integer >= 8, got 7", lambda t: D.binary_input(7))
bad(SHORT, "GiriDesign.staircase_input", ValueError, "`T` must be an integer >= 18, got 17", lambda t: D.staircase_input(17))
bad(SHORT, "GiriDesign.constant_input", ValueError, "`T` must be an integer >= 2, got 1", lambda t: D.constant_input(1))

# --- assumption A5
bad(GAIN, "identify_giri", ValueError, "B\\*\\(1\\) is not significantly different from 0", lambda t: hbjax.identify_giri(D, *records("zero_gain", 1000, 0.1)))
bad(GAIN, "GiriDesign.check_model", ValueError, "`model` has B\\(1\\) = 0; assumption A5", lambda t: D.check_model(ZERO_GAIN, assumptions=True))

# --- mu = 0, or a swing that does not cross the gap
bad(MU, "normalise", ValueError, "mu = P2\\(-h_m\\) - P1\\(h_m\\) is 0 for this `model`", lambda t: hbjax.normalise(MU_ZERO, 1.0))
bad(MU, "GiriDesign.check_model", ValueError, "v = \\+h_m does not put the output on P1.*assumption A4", lambda t: hbjax.GiriDesign(2, 3, 0.5).check_model(M, assumptions=True))
SMALL_H = hbjax.GiriDesign(2, 3, 0.5)  # +-0.5 stays inside the band of the default system
bad(MU, "identify_giri", ValueError, "v2 does not excite A, B\\* \\(does the \\+-h_m swing cross the backlash gap\\? assumption A4\\)", lambda t: hbjax.identify_giri(SMALL_H, *(np.asarray(hbjax.simulate(M, v)) for v in (SMALL_H.constant_input(400), SMALL_H.binary_input(400), SMALL_H.staircase_input(400)))))

# --- assumption A3
bad(UNSTABLE_A, "simulate", ValueError, "overflows to inf/NaN from sample \\d+ on: the ARX block of `model` is unstable", lambda t: hbjax.simulate(UNSTABLE, np.full(5000, H_M)))
bad(UNSTABLE_A, "GiriDesign.check_model", ValueError, "`model` has an unstable A \\(largest pole modulus 1.35", lambda t: D.check_model(UNSTABLE, assumptions=True))
bad(UNSTABLE_A, "identify_giri", ValueError, "the estimated A is unstable \\(assumption A3 fails\\)", lambda t: hbjax.identify_giri(D, *records("unstable")))

# --- crossing branches
bad(CROSS, "GiriDesign.check_model", ValueError, "branches P1, P2 of `model` cross near v = -3.09", lambda t: D.check_model(CROSSING, assumptions=True))

# --- monte_carlo
# One record length and batch size for every study here: the compiled chunk is reused.
MC = dict(noise_std=0.1, lengths=[40], realisations=8, key=jax.random.key(0), progress=False)


def mc(model=M, design=D, **kw):
    return hbjax.monte_carlo(model, design, **{**MC, **kw})


bad(WRONG_TYPE, "monte_carlo", TypeError, "`model` must be an hbjax.Hammerstein", lambda t: mc(model=ARX))
bad(WRONG_TYPE, "monte_carlo", TypeError, "`design` must be an hbjax.GiriDesign", lambda t: mc(design=(2, 3, 4.0)))
bad(WRONG_TYPE, "monte_carlo", TypeError, "`noise_std` must be a real number", lambda t: mc(noise_std="0.1"))
bad(WRONG_TYPE, "monte_carlo", TypeError, "`noise_std` must be a real number", lambda t: mc(noise_std=True))
bad(OPTION, "monte_carlo", ValueError, "`estimator` must be 'giri', 'refined' or a callable", lambda t: mc(estimator="mle"))
bad(OPTION, "monte_carlo", ValueError, "`noise` must be 'equation', 'output' or a callable", lambda t: mc(noise="pink"))
bad(WRONG_TYPE, "monte_carlo", TypeError, "`devices` must be None or a non-empty sequence", lambda t: mc(devices=["cpu"]))
bad(WRONG_TYPE, "monte_carlo", TypeError, "`devices` must be None or a non-empty sequence of jax.Device, got int", lambda t: mc(devices=0))
bad(EMPTY, "monte_carlo", ValueError, "`devices` must be None or a non-empty sequence of jax.Device, got an empty", lambda t: mc(devices=[]))
bad(KEY, "monte_carlo", TypeError, "`key` must be a single JAX PRNG key.*got int", lambda t: mc(key=0))
bad(KEY, "monte_carlo", TypeError, "`key` must be a single JAX PRNG key.*got NoneType", lambda t: mc(key=None))
bad(KEY, "monte_carlo", TypeError, "`key` must be a single JAX PRNG key.*got Generator", lambda t: mc(key=np.random.default_rng(0)))
bad(KEY, "monte_carlo", TypeError, "`key` must be a single JAX PRNG key.*shape \\(2,\\)", lambda t: mc(key=jax.random.split(jax.random.key(0), 2)))
bad(KEY, "monte_carlo", TypeError, "`key` must be a single JAX PRNG key.*dtype float64", lambda t: mc(key=jnp.zeros(2)))
bad(RANK, "monte_carlo", ValueError, "the `noise` callable must return a float record of shape \\(40,\\)", lambda t: mc(noise=lambda k, n: jnp.zeros((n, 2))))
bad(LENGTH, "monte_carlo", ValueError, "the `noise` callable must return a float record of shape \\(40,\\)", lambda t: mc(noise=lambda k, n: jnp.zeros(n + 1)))
bad(EMPTY, "monte_carlo", ValueError, "`lengths` must hold at least one record length", lambda t: mc(lengths=[]))
bad(NONFINITE, "monte_carlo", ValueError, "`noise_std` must be a finite number >= 0, got nan", lambda t: mc(noise_std=np.nan))
bad(NONFINITE, "monte_carlo", TypeError, "`lengths` must be an integer, got nan", lambda t: mc(lengths=[np.nan]))
bad(DTYPE, "monte_carlo", ValueError, "must return a float record.*dtype int", lambda t: mc(noise=lambda k, n: jnp.zeros(n, int)))
bad(ORDER, "monte_carlo", ValueError, "`realisations` must be an integer >= 1, got -3", lambda t: mc(realisations=-3))
bad(ORDER, "monte_carlo", TypeError, "`realisations` must be an integer, got 2.0", lambda t: mc(realisations=2.0))
bad(ORDER, "monte_carlo", TypeError, "`lengths` must be an integer, got 100.5", lambda t: mc(lengths=[100.5]))
bad(RANK, "monte_carlo", TypeError, "`lengths` must be a flat sequence of integers, got a nested one", lambda t: mc(lengths=[[300, 600]]))
bad(WRONG_TYPE, "monte_carlo", TypeError, "`estimator` must return an object with `.model` .* got int", lambda t: mc(estimator=lambda design, y1, y2, y3: 3))
bad(ORDER, "monte_carlo", ValueError, "`lengths` must be distinct", lambda t: mc(lengths=[40, 40]))
bad(ORDER, "monte_carlo", ValueError, "`chunk_size` must be an integer >= 1, got 0", lambda t: mc(chunk_size=0))
bad(SHORT, "monte_carlo", ValueError, "`lengths` \\[17\\] are shorter than one period of v3", lambda t: mc(lengths=[17]))
bad(NONFINITE, "monte_carlo", ValueError, "`noise_std` must be a finite number >= 0, got -1", lambda t: mc(noise_std=-1.0))
bad(COEF, "monte_carlo", ValueError, "orders na=1, nb=2, m=3 but the design expects", lambda t: mc(model=model_with(a=[0.5])))
bad(COEF, "monte_carlo", ValueError, "orders na=2, nb=2, m=2 but the design expects", lambda t: mc(model=model_with(c1=[0.0, 1.0], c2=[1.0, 1.0])))
bad(UNSTABLE_A, "monte_carlo", ValueError, "`model` has an unstable A", lambda t: mc(model=UNSTABLE))
bad(GAIN, "monte_carlo", ValueError, "`model` has B\\(1\\) = 0", lambda t: mc(model=ZERO_GAIN))
bad(CROSS, "monte_carlo", ValueError, "branches P1, P2 of `model` cross", lambda t: mc(model=CROSSING))
bad(MU, "monte_carlo", ValueError, "v = \\+h_m does not put the output on P1", lambda t: mc(design=SMALL_H))

# --- refine, fit, crlb
T_R = 300
V_R = 1.5 * H_M * np.sin(np.arange(T_R) / 7.0)  # sweeps both branches
Y_R = np.asarray(hbjax.simulate(M, V_R, 0.1 * np.random.default_rng(3).standard_normal(T_R)))
REC = (V_R, Y_R)
MN = hbjax.normalise(M, H_M)
KEY0 = jax.random.key(0)
FIT = dict(na=2, nb=2, m=3, key=KEY0, starts=2, max_steps=8)


def fit(recordings=REC, **kw):
    return hbjax.fit(recordings, **{**FIT, **kw})


bad(WRONG_TYPE, "refine", TypeError, "`model` must be an hbjax.Hammerstein", lambda t: hbjax.refine(BL, REC))
bad(WRONG_TYPE, "refine", TypeError, "`recordings` must be a \\(v, y\\) pair or a non-empty list", lambda t: hbjax.refine(MN, "data.csv"))
bad(WRONG_TYPE, "refine", TypeError, "`recordings\\[1\\]` must be a \\(v, y\\) pair", lambda t: hbjax.refine(MN, [REC, (V_R,)]))
bad(WRONG_TYPE, "refine", TypeError, "`h_m` must be a real number", lambda t: hbjax.refine(MN, REC, h_m="4"))
bad(WRONG_TYPE, "refine", TypeError, "`rtol`", lambda t: hbjax.refine(MN, REC, h_m=H_M, rtol="a"))
bad(WRONG_TYPE, "crlb", TypeError, "`model` must be an hbjax.Hammerstein", lambda t: hbjax.crlb(BL, REC, noise_std=0.1))
bad(WRONG_TYPE, "crlb", TypeError, "`noise_std` must be a real number, got 'x'", lambda t: hbjax.crlb(MN, REC, noise_std="x", h_m=H_M))
bad(LENGTH, "CRLBResult.summary", ValueError, "`names` must hold one name per parameter \\(10\\), got 1", lambda t: hbjax.crlb(MN, REC, noise_std=0.1, h_m=H_M).summary(names=["a1"]))
bad(WRONG_TYPE, "CRLBResult.summary", TypeError, "`names` must be a list of 10 parameter names, got the string 'abc'", lambda t: hbjax.crlb(MN, REC, noise_std=0.1, h_m=H_M).summary(names="abc"))
bad(WRONG_TYPE, "fit", TypeError, "`starts` must be an integer, got '4'", lambda t: fit(starts="4"))
bad(RANK, "refine", ValueError, "`recordings v` must be a 1-D array, got shape \\(300, 1\\)", lambda t: hbjax.refine(MN, (V_R[:, None], Y_R)))
bad(RANK, "crlb", TypeError, "`noise_std` must be a real number", lambda t: hbjax.crlb(MN, REC, noise_std=np.array([0.1, 0.2]), h_m=H_M))
bad(LENGTH, "refine", ValueError, "in `recordings`, v has 300 samples and y has 299", lambda t: hbjax.refine(MN, (V_R, Y_R[:-1])))
bad(LENGTH, "fit", ValueError, "in `recordings\\[1\\]`, v has 10 samples and y has 9", lambda t: fit([REC, (V_R[:10], Y_R[:9])]))
bad(EMPTY, "refine", TypeError, "`recordings` must be a \\(v, y\\) pair or a non-empty list", lambda t: hbjax.refine(MN, []))
bad(EMPTY, "fit", ValueError, "`recordings` must hold at least 2 samples, got 0", lambda t: fit((np.zeros(0), np.zeros(0))))
bad(NONFINITE, "refine", ValueError, "`recordings y` contains NaN or inf \\(1 samples, first at index 299\\)", lambda t: hbjax.refine(MN, (V_R, with_nan(Y_R, 299))))
bad(NONFINITE, "fit", ValueError, "`recordings v` contains NaN or inf", lambda t: fit((with_nan(V_R, 0, np.inf), Y_R)))
bad(NONFINITE, "crlb", ValueError, "`noise_std` must be a finite number > 0, got nan", lambda t: hbjax.crlb(MN, REC, noise_std=np.nan, h_m=H_M))
bad(NONFINITE, "refine", ValueError, "`rtol`", lambda t: hbjax.refine(MN, REC, h_m=H_M, rtol=np.nan))
bad(MAGNITUDE, "refine", ValueError, "`recordings y` reaches a magnitude of only [0-9.]+e-1[0-9][0-9]; the estimators' variances", lambda t: hbjax.refine(MN, (V_R, Y_R * 1e-150)))
bad(MAGNITUDE, "refine", ValueError, "`recordings y` reaches a magnitude of [0-9.]+e\\+1[0-9][0-9]; the estimators form sums of squares", lambda t: hbjax.refine(MN, (V_R, Y_R * 1e150)))
bad(MAGNITUDE, "fit", ValueError, "`recordings y` reaches a magnitude of only", lambda t: hbjax.fit((V_R, Y_R * 1e-150), na=2, nb=2, m=3, key=KEY0))
bad(NONFINITE, "crlb", ValueError, "`recordings y` contains NaN or inf", lambda t: hbjax.crlb(MN, (V_R, with_nan(Y_R)), noise_std=0.1, h_m=H_M))
bad(DTYPE, "refine", TypeError, "`recordings y` must be real", lambda t: hbjax.refine(MN, (V_R, Y_R + 0j)))
bad(ORDER, "fit", ValueError, "`na` must be an integer >= 0, got -1", lambda t: fit(na=-1))
bad(ORDER, "fit", ValueError, "`nb` must be an integer >= 1, got 0", lambda t: fit(nb=0))
bad(ORDER, "fit", TypeError, "`m` must be an integer, got 2.0", lambda t: fit(m=2.0))
bad(ORDER, "fit", ValueError, "`starts` must be an integer >= 1, got 0", lambda t: fit(starts=0))
bad(ORDER, "refine", ValueError, "`max_steps` must be an integer >= 1, got 0", lambda t: hbjax.refine(MN, REC, max_steps=0))
bad(ORDER, "refine", TypeError, "`max_steps` must be an integer, got 2.5", lambda t: hbjax.refine(MN, REC, max_steps=2.5))
bad(ORDER, "refine", ValueError, "`restarts` must be an integer >= 0, got -1", lambda t: hbjax.refine(MN, REC, restarts=-1))
bad(ORDER, "refine", ValueError, "`rtol`", lambda t: hbjax.refine(MN, REC, h_m=H_M, rtol=-1.0))
bad(H_M_BAD, "refine", ValueError, "`h_m` must be a finite number > 0, got 0", lambda t: hbjax.refine(MN, REC, h_m=0))
bad(H_M_BAD, "crlb", ValueError, "`h_m` must be a finite number > 0, got -1", lambda t: hbjax.crlb(MN, REC, noise_std=0.1, h_m=-1))
bad(OPTION, "refine", ValueError, "`criterion` must be one of \\('prediction', 'simulation'\\), got 'mse'", lambda t: hbjax.refine(MN, REC, criterion="mse"))
bad(OPTION, "crlb", ValueError, "`criterion` must be one of", lambda t: hbjax.crlb(MN, REC, noise_std=0.1, criterion="x"))
bad(OPTION, "fit", ValueError, "`criterion` must be one of", lambda t: fit(criterion=None))
bad(SHORT, "refine", ValueError, "`recordings` hold 5 samples in all; refining 9 free parameters needs more", lambda t: hbjax.refine(MN, (V_R[:5], Y_R[:5])))
bad(SHORT, "fit", ValueError, "`recordings` hold 10 samples; fitting 9 free parameters needs more than 18", lambda t: fit((V_R[:10], Y_R[:10])))
bad(GAIN, "refine", ValueError, "the initial `model` has B\\(1\\) = sum\\(b\\) = 0.*assumption A5", lambda t: hbjax.refine(ZERO_GAIN, REC))
bad(GAIN, "normalise_static_gain", ValueError, "`model` has B\\(1\\) = sum\\(b\\) = 0", lambda t: hbjax.normalise_static_gain(ZERO_GAIN))
bad(MU, "refine", ValueError, "mu = P2\\(-h_m\\) - P1\\(h_m\\) is 0.0 for the initial `model`", lambda t: hbjax.refine(MU_ZERO_AT_1, (V_R, Y_R), h_m=1.0))
bad(MU, "crlb", ValueError, "`model` is not normalised: P2\\(-h_m\\) - P1\\(h_m\\) = -5.52, expected 1", lambda t: hbjax.crlb(M, REC, noise_std=0.1, h_m=H_M))
bad(KEY, "fit", TypeError, "`key` must be a single JAX PRNG key .*got int 0", lambda t: fit(key=0))
bad(KEY, "fit", TypeError, "`key` must be a (single )?JAX PRNG key .*float64", lambda t: fit(key=jnp.zeros(2)))
bad(KEY, "fit", TypeError, "`key` must be a (single )?JAX PRNG key", lambda t: fit(key=jax.random.split(KEY0, 2)))
bad(IDENT, "crlb", ValueError, "[Ff]isher information is singular", lambda t: hbjax.crlb(MN, (V_R[:3], Y_R[:3]), noise_std=0.1, h_m=H_M))
bad(IDENT, "crlb", ValueError, "[Ff]isher information is singular", lambda t: hbjax.crlb(MN, (np.full(T_R, H_M), Y_R), noise_std=0.1, h_m=H_M))

bad(WRONG_TYPE, "separable_ls", TypeError, "`model` must be an hbjax.Hammerstein", lambda t: hbjax.separable_ls(ARX, REC))
bad(NONFINITE, "separable_ls", ValueError, "`recordings v` contains NaN or inf", lambda t: hbjax.separable_ls(MN, (with_nan(V_R), Y_R), h_m=H_M))
bad(SHORT, "separable_ls", ValueError, "`recordings` hold 5 samples; 9 free parameters need more", lambda t: hbjax.separable_ls(MN, (V_R[:5], Y_R[:5]), h_m=H_M))
bad(MU, "separable_ls", ValueError, "mu = P2\\(-h_m\\) - P1\\(h_m\\) is 0.0", lambda t: hbjax.separable_ls(MU_ZERO_AT_1, REC, h_m=1.0))
bad(ORDER, "separable_ls", ValueError, "`rtol`", lambda t: hbjax.separable_ls(MN, REC, h_m=H_M, rtol=-1.0))

# --- diagnose
T_D = 600
V_D = H_M * np.sin(np.arange(T_D) / 20.0)
Y_D = np.asarray(hbjax.simulate(M, V_D, 0.1 * np.random.default_rng(4).standard_normal(T_D)))
bad(WRONG_TYPE, "diagnose", TypeError, "`model` must be an hbjax.Hammerstein, got Backlash", lambda t: hbjax.diagnose(BL, V_D, Y_D))
bad(WRONG_TYPE, "diagnose", TypeError, "`effects`", lambda t: hbjax.diagnose(M, V_D, Y_D, effects=3))
bad(RANK, "diagnose", ValueError, "`v` must be a 1-D array, got shape \\(600, 1\\)", lambda t: hbjax.diagnose(M, V_D[:, None], Y_D))
bad(LENGTH, "diagnose", ValueError, "`v` has 600, `y` has 599 samples", lambda t: hbjax.diagnose(M, V_D, Y_D[:-1]))
bad(EMPTY, "diagnose", ValueError, "record too short for `holdout`=0.3: 0 samples", lambda t: hbjax.diagnose(M, [], []))
bad(NONFINITE, "diagnose", ValueError, "`y` contains NaN or inf \\(1 samples, first at index 0\\)", lambda t: hbjax.diagnose(M, V_D, with_nan(Y_D, 0)))
bad(NONFINITE, "diagnose", ValueError, "`holdout` must be a fraction in \\(0, 1\\), got nan", lambda t: hbjax.diagnose(M, V_D, Y_D, holdout=np.nan))
bad(DTYPE, "diagnose", TypeError, "`v` must be real", lambda t: hbjax.diagnose(M, V_D + 0j, Y_D))
bad(DTYPE, "diagnose", TypeError, "`channels\\['w'\\]` must be a numeric array, got str", lambda t: hbjax.diagnose(M, V_D, Y_D, channels={"w": "abc"}))
bad(WRONG_TYPE, "diagnose", TypeError, "`channels` names must be strings, got 3", lambda t: hbjax.diagnose(M, V_D, Y_D, channels={3: np.ones(len(V_D))}))
bad(ORDER, "diagnose", ValueError, "`holdout` must be a fraction in \\(0, 1\\), got 1.5", lambda t: hbjax.diagnose(M, V_D, Y_D, holdout=1.5))
bad(ORDER, "diagnose", TypeError, "`holdout` must be a fraction in \\(0, 1\\), got True", lambda t: hbjax.diagnose(M, V_D, Y_D, holdout=True))
bad(SHORT, "diagnose", ValueError, "record too short for `holdout`=0.3: 100 samples give 70 to fit", lambda t: hbjax.diagnose(M, V_D[:100], Y_D[:100]))
# a NumPy float is a fraction like any other: refused here for the short record only
bad(SHORT, "diagnose", ValueError, "record too short for `holdout`=0.3\\d*: 100 samples", lambda t: hbjax.diagnose(M, V_D[:100], Y_D[:100], holdout=np.float32(0.3)))
bad(OPTION, "diagnose", ValueError, "unknown effect name\\(s\\) in `effects`: \\['friction'\\]", lambda t: hbjax.diagnose(M, V_D, Y_D, effects=["friction"]))
bad(KEY, "diagnose", TypeError, "`key` must be a single JAX PRNG key .* or None, got int 0", lambda t: hbjax.diagnose(M, V_D, Y_D, key=0))
bad(UNSTABLE_A, "diagnose", ValueError, "unstable", lambda t: hbjax.diagnose(UNSTABLE, V_D, Y_D, effects=["parameter_mismatch"]))

bad(OPTION, "concealed_recording", ValueError, "unknown `effect` 'friction'", lambda t: hbjax.concealed_recording("friction"))
bad(OPTION, "concealed_recording", ValueError, "`system` must be an index 0..2, got 5", lambda t: hbjax.concealed_recording(None, system=5))
bad(OPTION, "concealed_recording", ValueError, "`inputs` must be one of \\('steps', 'smooth', 'sines'\\), got 'noise'", lambda t: hbjax.concealed_recording(None, inputs="noise"))
bad(ORDER, "concealed_recording", ValueError, "`n` must be an integer >= 1, got -5", lambda t: hbjax.concealed_recording(None, n=-5))
bad(ORDER, "concealed_recording", TypeError, "`n` must be an integer, got 2.5", lambda t: hbjax.concealed_recording(None, n=2.5))
bad(ORDER, "concealed_recording", ValueError, "`system` must be an index 0..2, got True", lambda t: hbjax.concealed_recording(None, system=True))
bad(NONFINITE, "concealed_recording", ValueError, "`noise` must be a finite number >= 0", lambda t: hbjax.concealed_recording(None, noise=-1.0))
bad(KEY, "concealed_recording", TypeError, "`key` must be a single JAX PRNG key .* or None, got int", lambda t: hbjax.concealed_recording(None, key=0))

# --- fit_percent
FIT_Y = np.sin(np.arange(10.0))
bad(WRONG_TYPE, "fit_percent", TypeError, "`y` must be a numeric array, got str", lambda t: hbjax.fit_percent("y", FIT_Y))
bad(RANK, "fit_percent", ValueError, "`y` must be a 1-D array, got shape \\(10, 2\\)", lambda t: hbjax.fit_percent(np.stack([FIT_Y, FIT_Y], 1), np.ones((10, 2))))
bad(LENGTH, "fit_percent", ValueError, "`y` has 10, `y_hat` has 5 samples", lambda t: hbjax.fit_percent(FIT_Y, FIT_Y[:5]))
bad(LENGTH, "fit_percent", ValueError, "`y` has 10, `y_hat` has 1 samples", lambda t: hbjax.fit_percent(np.arange(10.0), [4.5]))  # no broadcasting
bad(EMPTY, "fit_percent", ValueError, "`y` must hold at least one sample", lambda t: hbjax.fit_percent([], []))
bad(NONFINITE, "fit_percent", ValueError, "`y` contains NaN or inf", lambda t: hbjax.fit_percent(np.full(10, np.nan), FIT_Y))
bad(NONFINITE, "fit_percent", ValueError, "`y_hat` contains NaN or inf", lambda t: hbjax.fit_percent(FIT_Y, with_nan(FIT_Y)))
bad(IDENT, "fit_percent", ValueError, "`y` is constant: the fit percent is undefined for an output with no spread", lambda t: hbjax.fit_percent(np.ones(10), np.zeros(10)))
bad(IDENT, "fit_percent", ValueError, "`y` is constant", lambda t: hbjax.fit_percent(np.full(10, 5.0), np.full(10, 5.001)))

# --- figures (hbjax.plot): every argument checked on entry, before anything is drawn
REC_P = hbjax.Recording(V, Y, channels={"f": Y})
bad(WRONG_TYPE, "plot_backlash", TypeError, "`backlash` must be an hbjax.Backlash, got Hammerstein \\(pass the model's `.backlash`\\)", lambda t: hbjax.plot.plot_backlash(M, (-5, 5)))
bad(WRONG_TYPE, "plot_backlash", TypeError, "`v_range` must be a pair \\(lo, hi\\) of real numbers, got 5", lambda t: hbjax.plot.plot_backlash(BL, 5))
bad(WRONG_TYPE, "plot_backlash", TypeError, "`ax` must be None or a matplotlib Axes, got str", lambda t: hbjax.plot.plot_backlash(BL, (-5, 5), ax="x"))
bad(RANGE, "plot_backlash", ValueError, "`v_range` must be \\(lo, hi\\) with finite lo < hi, got \\(5, -5\\)", lambda t: hbjax.plot.plot_backlash(BL, (5, -5)))
bad(WRONG_TYPE, "plot_staircase", TypeError, "`design` must be an hbjax.GiriDesign, got NoneType", lambda t: hbjax.plot.plot_staircase(None, BL))
bad(WRONG_TYPE, "plot_staircase", TypeError, "`backlash` must be an hbjax.Backlash, got Hammerstein", lambda t: hbjax.plot.plot_staircase(D, M))
bad(ORDER, "plot_staircase", ValueError, "`periods` must be an integer >= 1, got 0", lambda t: hbjax.plot.plot_staircase(D, BL, periods=0))
bad(WRONG_TYPE, "plot_recording", TypeError, "`rec` must be an hbjax.Recording, got tuple", lambda t: hbjax.plot.plot_recording((V, Y)))
bad(OPTION, "plot_recording", ValueError, "`channels` names \\['g'\\] not in the recording; its channels: \\['f'\\]", lambda t: hbjax.plot.plot_recording(REC_P, channels=["g"]))
bad(WRONG_TYPE, "plot_recording", TypeError, "`channels` must be True, False, None or a list of channel names, got 'f'", lambda t: hbjax.plot.plot_recording(REC_P, channels="f"))
bad(LENGTH, "plot_recording", ValueError, "`axes` must be None or a sequence of 3 matplotlib Axes, got 0 Axes", lambda t: hbjax.plot.plot_recording(REC_P, axes=[]))
bad(WRONG_TYPE, "plot_monte_carlo", TypeError, "`study` must be an hbjax.Study, got str", lambda t: hbjax.plot.plot_monte_carlo("x"))
bad(WRONG_TYPE, "plot_diagnosis", TypeError, "`d` must be an hbjax.Diagnosis, got str", lambda t: hbjax.plot.plot_diagnosis("x"))
bad(WRONG_TYPE, "plot_output", TypeError, "`y_measured` must be a numeric array, got NoneType", lambda t: hbjax.plot.plot_output(None, Y))
bad(LENGTH, "plot_output", ValueError, "`y_measured` has 10, `y_simulated` has 5 samples", lambda t: hbjax.plot.plot_output(np.ones(10), np.ones(5)))
bad(RANK, "plot_output", ValueError, "`y_measured` must be a 1-D array, got shape \\(10, 2\\)", lambda t: hbjax.plot.plot_output(np.ones((10, 2)), np.ones((10, 2))))
bad(EMPTY, "plot_output", ValueError, "`y_measured` must hold at least one sample", lambda t: hbjax.plot.plot_output([], []))
bad(RANGE, "plot_output", ValueError, "`window` must satisfy 0 <= start < stop <= 10 .*got \\(8, 2\\)", lambda t: hbjax.plot.plot_output(np.ones(10), np.ones(10), window=(8, 2)))
bad(RANGE, "plot_output", ValueError, "`window` must satisfy 0 <= start < stop <= 10 .*got \\(0, 100\\)", lambda t: hbjax.plot.plot_output(np.ones(10), np.ones(10), window=(0, 100)))
bad(WRONG_TYPE, "plot_output", TypeError, "`window` must be None or a pair \\(start, stop\\) of sample indices", lambda t: hbjax.plot.plot_output(np.ones(10), np.ones(10), window=5))
bad(RANGE, "plot_output", ValueError, "`dt` must be a finite number > 0, got -1", lambda t: hbjax.plot.plot_output(np.ones(10), np.ones(10), dt=-1))
bad(RANGE, "plot_compare", ValueError, "`window` must satisfy 0 <= start < stop <= 60", lambda t: hbjax.plot.plot_compare(M, V, Y, window=(0, 100)))
bad(LENGTH, "plot_resid", ValueError, "`axes` must be None or a sequence of 2 matplotlib Axes, got 1 Axes", lambda t: hbjax.plot.plot_resid(M, V, Y, axes=[_an_axes()]))

# --- bundled data sets
bad(OPTION, "datasets.brfd", ValueError, "unknown BRFD record `name` 'nope'; valid names: .*1Hz30lbtension1amplitude", lambda t: hbjax.datasets.brfd("nope"))
bad(OPTION, "datasets.brfd", ValueError, "unknown BRFD record `name` None", lambda t: hbjax.datasets.brfd(None))

# --- files
bad(FILES, "load_model", FileNotFoundError, "model file .*missing.json' does not exist", lambda t: hbjax.load_model(t / "missing.json"))
bad(FILES, "load_model", ModelFileError, "not a valid JSON model file", lambda t: hbjax.load_model(text_file(t, "m.json", model_file(t).read_text()[:200])))
bad(FILES, "load_model", ModelFileError, "not an hbjax model file", lambda t: hbjax.load_model(text_file(t, "m.json", '{"model": {}}')))
bad(FILES, "load_model", ModelFileError, "`model.backlash.c1` must hold 3 values", lambda t: hbjax.load_model(text_file(t, "m.json", re.sub(r'("c1": \{"array": \[)[^,]*,', r"\1", model_file(t).read_text()))))
bad(FILES, "load_model", TypeError, "`classes` must be a tuple of eqx.Module subclasses, got int", lambda t: hbjax.load_model(model_file(t), classes=5))
bad(FILES, "load_model", TypeError, "`classes` must hold eqx.Module subclasses only, got 'Gain'", lambda t: hbjax.load_model(model_file(t), classes=["Gain"]))
bad(FILES, "load_model", TypeError, "not their names\\), got the string 'Gain'", lambda t: hbjax.load_model(model_file(t), classes="Gain"))
bad(FILES, "load_model", ModelFileError, "format_version 99 is not supported", lambda t: hbjax.load_model(text_file(t, "m.json", model_file(t).read_text().replace('"format_version": 1', '"format_version": 99'))))
bad(FILES, "load_model", ModelFileError, "non-finite coefficients", lambda t: hbjax.load_model(text_file(t, "m.json", re.sub(r'("a": \{"array": \[)[^,]*', r'\1{"float": "nan"}', model_file(t).read_text()))))
bad(FILES, "save_model", FileExistsError, "already exists; pass overwrite=True", lambda t: hbjax.save_model(model_file(t), M))
bad(FILES, "save_model", FileNotFoundError, "folder .*nowhere' .* does not exist", lambda t: hbjax.save_model(t / "nowhere" / "m.json", M))
bad(FILES, "save_model", IsADirectoryError, "is a directory", lambda t: hbjax.save_model(t, M, overwrite=True))
bad(FILES, "load_recording", FileNotFoundError, "recording file .* does not exist", lambda t: hbjax.load_recording(t / "missing.csv"))
bad(FILES, "load_recording", ValueError, "the header names 'v' for 2 columns \\(0, 1\\); give the input column by its 0-based index", lambda t: hbjax.load_recording(text_file(t, "r.csv", "v,v,y\n1,2,3\n4,5,6\n"), input="v", output="y"))
bad(FILES, "load_recording", ValueError, "non-numeric cell 'x' at row 2, column 1 \\('y'\\)", lambda t: hbjax.load_recording(text_file(t, "r.csv", "v,y\n1,x\n")))
bad(FILES, "load_recording", ValueError, "not a readable .npz archive", lambda t: hbjax.load_recording(text_file(t, "r.npz", "not a zip")))
bad(FILES, "load_recording", ValueError, "not valid JSON", lambda t: hbjax.load_recording(text_file(t, "r.json", "{")))
bad(FILES, "save_recording", FileExistsError, "already exists", lambda t: hbjax.save_recording(text_file(t, "r.csv", "old"), hbjax.Recording(V, Y)))

# --- hostile content and output paths (tests/test_files_adversarial.py has the round trips)
MF = lambda t, text: text_file(t, "h.json", model_file(t).read_text().replace('"format_version": 1', text))  # noqa: E731
bad(HOSTILE, "load_model", ModelFileError, "not a valid JSON model file", lambda t: hbjax.load_model(MF(t, '"format_version": 1' + "0" * 5000)))
bad(HOSTILE, "load_model", ModelFileError, "not a valid JSON model file", lambda t: hbjax.load_model(MF(t, '"format_version": ' + "[" * 50000 + "]" * 50000)))
bad(HOSTILE, "load_model", ModelFileError, "not a valid JSON model file .*NaN", lambda t: hbjax.load_model(MF(t, '"format_version": NaN')))
bad(HOSTILE, "load_model", ModelFileError, "unknown model class 'hbjax.__main__.X'", lambda t: hbjax.load_model(text_file(t, "h.json", model_file(t).read_text().replace('"class": "Hammerstein"', '"class": "hbjax.__main__.X"', 1))))
bad(HOSTILE, "load_model", ModelFileError, "at most m = 64", lambda t: hbjax.load_model(text_file(t, "h.json", '{"format": "hbjax-model", "format_version": 1, "kind": "Backlash", "model": {"class": "Backlash", "fields": {"c1": {"array": [], "dtype": "float64", "shape": [9000000]}, "c2": {"array": [], "dtype": "float64", "shape": [9000000]}}}}')))
bad(HOSTILE, "Backlash", ValueError, "at most m = 64", lambda t: hbjax.Backlash(np.ones(65), np.ones(65)))
bad(HOSTILE, "load_recording", ValueError, "non-numeric cell '1_000' at row 2", lambda t: hbjax.load_recording(text_file(t, "r.csv", "v,y\n1_000,2\n")))
bad(HOSTILE, "load_recording", ValueError, "non-numeric cell '\uff11' at row 2", lambda t: hbjax.load_recording(text_file(t, "r.csv", "v,y\n\uff11,2\n")))
bad(HOSTILE, "load_recording", ValueError, "too large for a float64", lambda t: hbjax.load_recording(text_file(t, "r.json", '{"data": [[0, 1, 1%s]]}' % ("0" * 400))))
bad(HOSTILE, "load_recording", ValueError, "nested too deeply", lambda t: hbjax.load_recording(text_file(t, "r.json", "[" * 100000)))
bad(HOSTILE, "load_recording", ValueError, "'dt' must hold one real number", lambda t: hbjax.load_recording((np.savez(t / "r.npz", v=V, y=Y, dt=np.ones(2)), t / "r.npz")[1]))
bad(HOSTILE, "load_recording", ValueError, "array 'v' must be real", lambda t: hbjax.load_recording((np.savez(t / "r.npz", v=V + 1j, y=Y), t / "r.npz")[1]))
bad(HOSTILE, "load_recording", IsADirectoryError, "is a directory", lambda t: hbjax.load_recording(t))
bad(HOSTILE, "load_model", IsADirectoryError, "is a directory", lambda t: hbjax.load_model(t))
bad(HOSTILE, "normalise", ValueError, "`h_m` must be finite, got inf", lambda t: hbjax.normalise(M, np.inf))
bad(OUTPUTS, "save_recording", ValueError, "exceeds the largest float64", lambda t: hbjax.save_recording(t / "r.csv", hbjax.Recording([1.0, 2, 3], [1.0, 2, 3], dt=1e308)))
bad(OUTPUTS, "save_recording", ValueError, "BRFD layout", lambda t: hbjax.save_recording(t / "r.json", hbjax.Recording(V, Y)))
bad(OUTPUTS, "save_model", ValueError, "standard output", lambda t: hbjax.save_model("-", M))
bad(OUTPUTS, "hbjax simulate", CLIError, "exit 1: hbjax simulate: error: --out: '-' is not a file name", lambda t: cli("simulate", "--model", model_file(t), "--input", text_file(t, "v.csv", "v\n1\n2\n"), "--out", "-"))
bad(OUTPUTS, "hbjax montecarlo", CLIError, "exit 1: .*unsupported figure format 'bmpx'", lambda t: cli("montecarlo", "--config", text_file(t, "c.json", '{"noise_std": 0.1, "lengths": [40], "realisations": 2}'), "--out", t / "s.json", "--plot", t / "s.bmpx"))
bad(OUTPUTS, "hbjax montecarlo", CLIError, "exit 1: .*--out and --plot name the same file", lambda t: cli("montecarlo", "--config", text_file(t, "c.json", '{"noise_std": 0.1, "lengths": [40], "realisations": 2}'), "--out", t / "s.json", "--plot", t / "s.json"))
bad(OUTPUTS, "hbjax diagnose", CLIError, "exit 1: .*--json and --save-model name the same file", lambda t: cli("diagnose", "--model", model_file(t), text_file(t, "rec.csv", "v,y\n1,2\n"), "--json", t / "X", "--save-model", t / "X"))
bad(OUTPUTS, "hbjax signals", CLIError, "exit 1: .*v2.csv' already exists", lambda t: (text_file(t, "v2.csv", "keep"), cli("signals", "--design", "n=2,m=3,h_m=4", "--samples", 40, "--prefix", t / "v"))[1])
bad(CLI, "hbjax simulate", CLIError, "exit 1: .*--noise-std must be a finite number >= 0, got nan", lambda t: cli("simulate", "--model", model_file(t), "--input", text_file(t, "v.csv", "v\n1\n2\n"), "--out", t / "y.csv", "--noise-std", "nan"))
bad(CLI, "hbjax montecarlo", CLIError, "exit 1: .*`keep_estimates` must be true or false", lambda t: cli("montecarlo", "--config", text_file(t, "c.json", '{"noise_std": 0.1, "lengths": [40], "realisations": 2, "keep_estimates": "false"}'), "--out", t / "s.json", "--no-progress"))

# --- command line (in-process; exit status and the one-line message)
bad(CLI, "hbjax (no command)", CLIError, "exit 2: usage: hbjax", lambda t: cli())
bad(CLI, "hbjax show", CLIError, "exit 1: hbjax show: error: model file .* does not exist", lambda t: cli("show", t / "missing.json"))
bad(CLI, "hbjax show", CLIError, "exit 1: hbjax show: error: .*not a valid JSON model file", lambda t: cli("show", text_file(t, "m.json", "{")))
bad(CLI, "hbjax signals", CLIError, "exit 1: .*--design .*`h_m` must be a finite number > 0", lambda t: cli("signals", "--design", "n=2,m=3,h_m=0", "--samples", 40, "--prefix", t / "v"))
bad(CLI, "hbjax signals", CLIError, "exit 1: .*--design needs exactly n, m and h_m", lambda t: cli("signals", "--design", "n=2,m=3", "--samples", 40, "--prefix", t / "v"))
bad(CLI, "hbjax signals", CLIError, "exit 1: .*`--samples` must be an integer >= 18, got 10", lambda t: cli("signals", "--design", "n=2,m=3,h_m=4", "--samples", 10, "--prefix", t / "v"))
bad(CLI, "hbjax signals", CLIError, "exit 2: .*--samples: invalid int value", lambda t: cli("signals", "--design", "n=2,m=3,h_m=4", "--samples", "many"))
bad(CLI, "hbjax simulate", CLIError, "exit 1: hbjax simulate: error: --noise-std must be a finite number >= 0", lambda t: cli("simulate", "--model", model_file(t), "--input", text_file(t, "v.csv", "v\n1\n2\n"), "--out", t / "y.csv", "--noise-std", -1))
bad(CLI, "hbjax simulate", CLIError, "exit 1: .*not finite\\) at row 3", lambda t: cli("simulate", "--model", model_file(t), "--input", text_file(t, "v.csv", "v\n1\ninf\n"), "--out", t / "y.csv"))
bad(CLI, "hbjax simulate", CLIError, "exit 1: .*--out .* would replace the input file", lambda t: cli("simulate", "--model", model_file(t), "--input", text_file(t, "v.csv", "v\n1\n2\n"), "--out", model_file(t)))
bad(CLI, "hbjax simulate", CLIError, "exit 1: .*--out: .* already exists; pass --force", lambda t: cli("simulate", "--model", model_file(t), "--input", text_file(t, "v.csv", "v\n1\n2\n"), "--out", text_file(t, "old.csv", "old")))
bad(CLI, "hbjax montecarlo", CLIError, "exit 1: .*unknown config keys \\['sigma'\\]", lambda t: cli("montecarlo", "--config", text_file(t, "c.json", '{"sigma": 1, "noise_std": 0.1, "lengths": [40], "realisations": 2}'), "--out", t / "s.json", "--no-progress"))
bad(CLI, "hbjax montecarlo", CLIError, "exit 1: .*missing config keys \\['realisations'\\]", lambda t: cli("montecarlo", "--config", text_file(t, "c.json", '{"noise_std": 0.1, "lengths": [40]}'), "--out", t / "s.json", "--no-progress"))
bad(CLI, "hbjax montecarlo", CLIError, "exit 1: .*`lengths` must be a non-empty list of integers, got \\[\\[300\\]\\]", lambda t: cli("montecarlo", "--config", text_file(t, "c.json", '{"noise_std": 0.1, "lengths": [[300]], "realisations": 2}'), "--out", t / "s.json", "--no-progress"))
bad(CLI, "hbjax montecarlo", CLIError, "exit 1: .*`noise_std` must be a finite number >= 0", lambda t: cli("montecarlo", "--config", text_file(t, "c.json", '{"noise_std": -1, "lengths": [40], "realisations": 2}'), "--out", t / "s.json", "--no-progress"))
REC_CSV = "v,y\n" + "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in zip(V_R, Y_R))
bad(CLI, "hbjax identify fit", CLIError, "exit 1: hbjax identify fit: error: .*`--na` must be an integer >= 0, got -1", lambda t: cli("identify", "fit", "--na", -1, "--nb", 2, "--m", 3, text_file(t, "rec.csv", REC_CSV), "--out", t / "fit.json"))
bad(CLI, "hbjax identify fit", CLIError, "exit 2: .*--criterion: invalid choice: 'mse'", lambda t: cli("identify", "fit", "--na", 2, "--nb", 2, "--m", 3, "--criterion", "mse", text_file(t, "rec.csv", REC_CSV), "--out", t / "fit.json"))
bad(CLI, "hbjax identify fit", CLIError, "exit 1: .*non-numeric cell 'x' at row 3", lambda t: cli("identify", "fit", "--na", 2, "--nb", 2, "--m", 3, text_file(t, "rec.csv", "v,y\n1,2\n3,x\n"), "--out", t / "fit.json"))
DIAG_CSV = "v,y\n" + "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in zip(V_D, Y_D))
bad(CLI, "hbjax diagnose", CLIError, "exit 1: .*`--holdout` must be a fraction in \\(0, 1\\), got 1.5", lambda t: cli("diagnose", "--model", model_file(t), text_file(t, "rec.csv", DIAG_CSV), "--holdout", 1.5))
bad(CLI, "hbjax diagnose", CLIError, "exit 1: .*unknown effect name\\(s\\) in `--effects`: \\['friction'\\]", lambda t: cli("diagnose", "--model", model_file(t), text_file(t, "rec.csv", DIAG_CSV), "--effects", "friction"))
bad(CLI, "hbjax identify giri", CLIError, "exit 1: .*`y\\d` has \\d+ samples; it must cover at least", lambda t: cli("identify", "giri", "--design", "n=2,m=3,h_m=4", *[text_file(t, f"y{k}.csv", "y\n1\n2\n3\n") for k in (1, 2, 3)], "--out", t / "m2.json"))


bad(CLI, "hbjax diagnose", CLIError, "exit 1: .*--effects '' names no effect", lambda t: cli("diagnose", "--model", model_file(t), text_file(t, "rec.csv", DIAG_CSV), "--effects", ""))


def frame(**columns):
    import pandas

    return pandas.DataFrame(columns)


# --- found by a probe of the public API: data a cast or a default would have let through
bad(DTYPE, "Recording", TypeError, "the input column 'v' must hold real numbers, got dtype complex", lambda t: hbjax.Recording.from_dataframe(frame(v=V + 1j, y=Y), input="v", output="y"))
bad(DTYPE, "Recording", TypeError, "the channel column 'c' must hold real numbers", lambda t: hbjax.Recording.from_dataframe(frame(v=V, y=Y, c=V * 1j), input="v", output="y"))
bad(DTYPE, "Recording", TypeError, "the input column 'v' must hold real numbers", lambda t: hbjax.Recording.from_dataframe(frame(v=V.astype(str), y=Y), input="v", output="y"))
bad(OPTION, "Recording", ValueError, "the input and the output are the same column", lambda t: hbjax.Recording.from_dataframe(frame(v=V, y=Y), input="v", output="v"))
bad(DTYPE, "compare", TypeError, "`v` must be real, got complex", lambda t: hbjax.compare(M, frame(v=V + 1j, y=Y)))
bad(DTYPE, "resid", TypeError, "`v` must be a numeric array, got dtype object", lambda t: hbjax.resid(M, frame(v=V.astype(str), y=Y)))
bad(WRONG_TYPE, "compare", TypeError, "`v` is a recording, which holds its own output", lambda t: hbjax.compare(M, hbjax.Recording(V, Y), Y))
bad(IDENT, "compare", ValueError, "`y` is constant: the fit .* is undefined", lambda t: hbjax.compare(M, V, np.full(V.shape, 1000.0)))
bad(IDENT, "diagnose", ValueError, "`v` is constant: a constant input holds the backlash", lambda t: hbjax.diagnose(M, np.ones(600), np.linspace(0, 1, 600)))
bad(FILES, "load_recording", TypeError, "`path` must be a file name .a str or os.PathLike., got NoneType", lambda t: hbjax.load_recording(None))
bad(FILES, "load_model", TypeError, "`path` must be a file name .a str or os.PathLike., got NoneType", lambda t: hbjax.load_model(None))
bad(FILES, "save_model", TypeError, "`path` must be a file name .a str or os.PathLike., got int", lambda t: hbjax.save_model(3, M))
bad(FILES, "save_recording", TypeError, "`path` must be a file name .a str or os.PathLike., got NoneType", lambda t: hbjax.save_recording(None, hbjax.Recording(V, Y)))
bad(WRONG_TYPE, "plot_compare", TypeError, "`result` must be a Comparison, an hbjax model, .* got str", lambda t: hbjax.plot.plot_compare("x"))
bad(WRONG_TYPE, "Recording", TypeError, "`recording` must be an hbjax.Recording .its times place the trend., got ndarray", lambda t: hbjax.Recording(V, Y, dt=1.0).detrend().trend.restore(np.arange(5.0)))
bad(MAGNITUDE, "simulate", ValueError, "`model` is stable, so the values given .* are too large", lambda t: hbjax.simulate(M, V, y0=[1e308, -1e308]))
bad(OPTION, "identify_nominal", ValueError, "`criterion` must be one of", lambda t: hbjax.identify_nominal(V_D, Y_D, criterion="simulaton"))
bad(OPTION, "identify_nominal", ValueError, "`gap` must be a finite number > 0, got -1.0", lambda t: hbjax.identify_nominal(V_D, Y_D, gap=-1.0))
bad(OPTION, "identify_nominal", TypeError, "`gap` must be a real number, got '0.1'", lambda t: hbjax.identify_nominal(V_D, Y_D, gap="0.1"))
bad(RANGE, "identify_nominal", ValueError, "`transient` must leave samples in the criterion", lambda t: hbjax.identify_nominal(V_D, Y_D, transient=T_D))
bad(ORDER, "identify_nominal", ValueError, "`transient` must be an integer >= 0, got -1", lambda t: hbjax.identify_nominal(V_D, Y_D, transient=-1))
bad(ORDER, "identify_nominal", ValueError, "`max_steps` must be an integer >= 1, got 0", lambda t: hbjax.identify_nominal(V_D, Y_D, max_steps=0))
bad(ORDER, "identify_nominal", TypeError, "`m` must be an integer, got '3'", lambda t: hbjax.identify_nominal(V_D, Y_D, m="3"))
bad(WRONG_TYPE, "identify_nominal", TypeError, "`start` must be an hbjax.Hammerstein, got str", lambda t: hbjax.identify_nominal(V_D, Y_D, start="x"))
bad(OPTION, "identify_nominal", ValueError, "`na`=1 differs from the `start` model's na = 2", lambda t: hbjax.identify_nominal(V_D, Y_D, na=1, start=M))
bad(ORDER, "fit", ValueError, "`m` must be an integer >= 2 to identify a model, got 1", lambda t: hbjax.fit(REC, na=2, nb=2, m=1, key=jax.random.key(0)))
bad(ORDER, "refine", ValueError, "`model.backlash.m` must be an integer >= 2 to identify a model, got 1", lambda t: hbjax.refine(hbjax.Hammerstein(hbjax.Backlash([-1.0], [1.0]), hbjax.ARX([0.5], [1.0])), REC))
bad(ORDER, "GiriDesign", ValueError, "`m` must be an integer >= 2 for the paper's design, got 1", lambda t: hbjax.GiriDesign(2, 1, 4.0))
bad(UNSTABLE_A, "refine", ValueError, "`model` has an unstable A \\(largest pole modulus 1.3.*simulation criterion cannot start from it", lambda t: hbjax.refine(hbjax.Hammerstein(MN.backlash, hbjax.ARX([-1.5, 0.2], MN.arx.b)), REC, h_m=H_M, criterion="simulation"))
bad(OPTION, "fit", ValueError, "`min_sim_fit` must be a finite number \\(percent\\) below 100, got 200.0", lambda t: hbjax.fit(REC, min_sim_fit=200.0, **FIT))
bad(NONFINITE, "resid", ValueError, "`y` contains NaN or inf \\(1 samples, first at index 299\\)", lambda t: hbjax.resid(M, V_R, np.r_[Y_R[:-1], np.inf]))
bad(RANK, "simulate", ValueError, "`y0` must hold the na = 2 output lags .*got a scalar", lambda t: hbjax.simulate(M, V, y0=1.0))
bad(WRONG_TYPE, "plot_resid", TypeError, "`result` must be an hbjax.ResidualAnalysis .*got Comparison", lambda t: hbjax.plot.plot_resid(hbjax.compare(M, V_R, Y_R)))
bad(WRONG_TYPE, "compare", TypeError, "`names` must be a list of labels, one per model, got the string 'ab'", lambda t: hbjax.compare([M, M], V_R, Y_R, names="ab"))
bad(ORDER, "select_structure", ValueError, "`m` must be an integer >= 2 to identify a model, got 1", lambda t: hbjax.select_structure(REC, na=2, nb=2, m=[1, 2], key=jax.random.key(0), progress=False))
bad(RANGE, "Recording", TypeError, "`start` must be an integer sample index or None, got 2.5", lambda t: hbjax.Recording(V, Y).slice(2.5, 10))
bad(HOSTILE, "load_model", ModelFileError, "\\.kind` must be 'jax' or 'numpy', got 'pickle'", lambda t: hbjax.load_model(text_file(t, "m.json", model_file(t).read_text().replace('"kind": "jax"', '"kind": "pickle"'))))


# ----------------------------------------------------------------------------- accepted inputs


@dataclasses.dataclass(frozen=True)
class Promoted:
    target: str
    what: str
    call: Callable[[], object]  # with the promoted input
    reference: Callable[[], object]  # the same input converted to float64 by hand


PROMOTED = [
    Promoted("simulate", "int64 v", lambda: hbjax.simulate(M, np.arange(-5, 5)), lambda: hbjax.simulate(M, np.arange(-5.0, 5.0))),
    Promoted("simulate", "float32 v", lambda: hbjax.simulate(M, V.astype(np.float32)), lambda: hbjax.simulate(M, V.astype(np.float32).astype(np.float64))),
    Promoted("simulate", "float32 jax v, int u0", lambda: hbjax.simulate(M, jnp.asarray(V, jnp.float32), u0=1), lambda: hbjax.simulate(M, V.astype(np.float32).astype(np.float64), u0=1.0)),
    Promoted("simulate", "bool v", lambda: hbjax.simulate(M, V > 0), lambda: hbjax.simulate(M, (V > 0).astype(float))),
    Promoted("simulate", "list v and noise", lambda: hbjax.simulate(M, [1, 2, 3], [0, 0, 1]), lambda: hbjax.simulate(M, np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.0, 1.0]))),
    Promoted("play", "float32 v", lambda: hbjax.play(BL, V.astype(np.float32)), lambda: hbjax.play(BL, V.astype(np.float32).astype(np.float64))),
    Promoted("predict", "int y", lambda: hbjax.predict(M, V, np.arange(60)), lambda: hbjax.predict(M, V, np.arange(60.0))),
    Promoted("Backlash", "int coefficients", lambda: hbjax.play(hbjax.Backlash([-1, 1], [1, 1]), V), lambda: hbjax.play(hbjax.Backlash([-1.0, 1.0], [1.0, 1.0]), V)),
    Promoted("ARX", "float32 coefficients", lambda: hbjax.simulate(hbjax.Hammerstein(BL, hbjax.ARX(np.float32([-0.5]), np.float32([1.0]))), V), lambda: hbjax.simulate(hbjax.Hammerstein(BL, hbjax.ARX([-0.5], [1.0])), V)),
    Promoted("identify_giri", "float32 records", lambda: hbjax.identify_giri(D, *(y.astype(np.float32) for y in records())).model, lambda: hbjax.identify_giri(D, *(y.astype(np.float32).astype(np.float64) for y in records())).model),
    Promoted("normalise", "int h_m", lambda: hbjax.normalise(M, 4), lambda: hbjax.normalise(M, 4.0)),
    Promoted("GiriDesign", "numpy integer n, int h_m", lambda: hbjax.GiriDesign(np.int64(2), np.int32(3), 4).staircase_input(40), lambda: D.staircase_input(40)),
    Promoted("unflatten_params", "float32 theta", lambda: hbjax.unflatten_params(M, THETA.astype(np.float32)), lambda: hbjax.unflatten_params(M, THETA.astype(np.float32).astype(np.float64))),
    Promoted("refine", "float32 records", lambda: hbjax.refine(MN, (V_R.astype(np.float32), Y_R.astype(np.float32)), h_m=H_M).model, lambda: hbjax.refine(MN, (V_R.astype(np.float32).astype(float), Y_R.astype(np.float32).astype(float)), h_m=H_M).model),
    Promoted("crlb", "int noise_std and h_m", lambda: hbjax.crlb(hbjax.normalise(M, 4), REC, noise_std=1, h_m=4).covariance, lambda: hbjax.crlb(MN, REC, noise_std=1.0, h_m=4.0).covariance),
    Promoted("Recording", "int lists", lambda: hbjax.Recording([1, 2], [3, 4]).v, lambda: np.array([1.0, 2.0])),
    Promoted("refine", "a pair of lists, and a list of such pairs", lambda: hbjax.refine(MN, [(list(V_R), list(Y_R)), (V_R.tolist(), Y_R.tolist())], h_m=H_M).model, lambda: hbjax.refine(MN, [(V_R, Y_R), (V_R, Y_R)], h_m=H_M).model),
]


# ----------------------------------------------------------------------------- traced checks


@dataclasses.dataclass(frozen=True)
class Traced:
    target: str
    fn: Callable  # fn(x) with x traced
    good: object
    bad: object
    match: str
    xfail_jit: str | None = None  # a known gap under jax.jit / eqx.filter_jit only


TRACED = [
    Traced("simulate (v)", lambda v: hbjax.simulate(M, v), V, with_nan(V), "`v` contains NaN or inf"),
    Traced("simulate (noise)", lambda xi: hbjax.simulate(M, V, xi), np.zeros(60), with_nan(np.zeros(60), 0, np.inf), "`noise` contains NaN or inf"),
    Traced("simulate (u0)", lambda u0: hbjax.simulate(M, V, u0=u0), 0.5, np.nan, "`u0` contains NaN or inf"),
    Traced("simulate (model)", lambda c: hbjax.simulate(model_with(c1=c), V), np.asarray(BL.c1), with_nan(BL.c1, 1), "`model` has NaN or inf coefficients"),
    Traced("play (v)", lambda v: hbjax.play(BL, v), V, with_nan(V), "`v` contains NaN or inf"),
    Traced("simulate (smoothing)", lambda s: hbjax.simulate(M, V, smoothing=s), 0.1, -1.0, "`smoothing` must be a finite number >= 0"),
    Traced("play (smoothing)", lambda s: hbjax.play(BL, V, smoothing=s), 0.1, np.nan, "`smoothing` must be a finite number >= 0"),
    Traced("predict (y)", lambda y: hbjax.predict(M, V, y), Y, with_nan(Y, 59, -np.inf), "`y` contains NaN or inf"),
    Traced("predict (model)", lambda a: hbjax.predict(model_with(a=a), V, Y), np.asarray(ARX.a), with_nan(ARX.a, 0), "`model` has NaN or inf coefficients"),
    Traced("normalise (h_m <= 0)", lambda h: hbjax.normalise(M, h).arx.b, H_M, 0.0, "`h_m` must be > 0"),
    Traced("normalise (mu = 0)", lambda h: hbjax.normalise(MU_ZERO_AT_1, h).arx.b, 2.0, 1.0, "mu = P2\\(-h_m\\) - P1\\(h_m\\) is 0"),
    Traced("crlb (y)", lambda y: hbjax.crlb(MN, (V_R, y), noise_std=0.1, h_m=H_M).covariance, Y_R, with_nan(Y_R, 7), "`recordings y` contains NaN or inf"),
    Traced("refine (y)", lambda y: hbjax.refine(MN, (V_R, y), h_m=H_M, max_steps=4, throw=False).model, Y_R, with_nan(Y_R, 7), "`recordings y` contains NaN or inf"),
    Traced("identify_giri (y2)", lambda y2: hbjax.identify_giri(D, records()[0], y2, records()[2], throw=False).result, records()[1], with_nan(records()[1], 100), "`y2` contains NaN or inf"),
]


# ----------------------------------------------------------------------------- tests


def _params(cases):
    return [
        pytest.param(c, id=f"{c.target}-{i}",
                     marks=[pytest.mark.xfail(reason=c.xfail, strict=True)] if c.xfail else [])
        for i, c in enumerate(cases)
    ]


@pytest.mark.parametrize("case", _params(CASES))
def test_bad_input_is_refused_with_a_clear_message(case, tmp_path):
    with pytest.raises(case.exc) as info:
        case.call(tmp_path)
    assert re.search(case.match, str(info.value), re.S), f"{info.value!s} !~ {case.match}"
    if case.exc is not CLIError:
        # One message naming what was wrong: never an internal error from deeper down.
        assert "Traceback" not in str(info.value)


def _leaves(x):
    return [np.asarray(leaf) for leaf in jax.tree_util.tree_leaves(x)]


@pytest.mark.parametrize("case", PROMOTED, ids=[f"{c.target}-{c.what}" for c in PROMOTED])
def test_promoted_inputs_give_the_float64_result_exactly(case):
    got, want = _leaves(case.call()), _leaves(case.reference())
    assert len(got) == len(want)
    for g, w in zip(got, want):
        assert g.dtype == w.dtype and g.shape == w.shape
        if g.dtype.kind == "f":
            assert g.dtype == np.float64
            assert np.all(np.isfinite(g))
        np.testing.assert_array_equal(g, w)


def _traced_params():
    out = []
    for transform in ("jax.jit", "eqx.filter_jit", "jax.vmap"):
        for c in TRACED:
            gap = c.xfail_jit if transform != "jax.vmap" else None
            marks = [pytest.mark.xfail(reason=gap, strict=True)] if gap else []
            out.append(pytest.param(c, transform, id=f"{transform}-{c.target}", marks=marks))
    return out


@pytest.mark.parametrize("case, transform", _traced_params())
def test_value_checks_survive_jit_and_vmap(case, transform):
    good, bad_ = jnp.asarray(case.good), jnp.asarray(case.bad)
    if transform == "jax.vmap":
        fn, good, bad_ = jax.vmap(case.fn), jnp.stack([good, good]), jnp.stack([good, bad_])
    else:
        fn = {"jax.jit": jax.jit, "eqx.filter_jit": eqx.filter_jit}[transform](case.fn)
    assert all(np.all(np.isfinite(leaf)) for leaf in _leaves(fn(good)))
    # The exception class depends on the transform and on how JAX reports callback errors
    # (EquinoxRuntimeError, JaxRuntimeError, ...); what must survive is the message.
    with pytest.raises(Exception) as info:
        jax.block_until_ready(fn(bad_))
    assert re.search(case.match, str(info.value), re.S)


def test_diverging_simulation_is_refused_only_when_it_overflows():
    # A short record of an unstable model is a valid (large) result; only inf/NaN is refused.
    y = hbjax.simulate(UNSTABLE, np.full(100, H_M))
    assert np.all(np.isfinite(y)) and np.abs(y[-1]) > 1e10


def test_check_model_accepts_increasing_and_decreasing_backlash():
    D.check_model(M, assumptions=True)
    decreasing = model_with(c1=[1.0, -0.9, 0.0], c2=[-1.0, -0.9, 0.0])
    D.check_model(decreasing, assumptions=True)


# Every bool flag of the public API: "no" or "false" is truthy, 0/1 a likely slip. Refused
# at the entry, before any work (the estimators below would otherwise run for seconds).
FLAGS = {
    "save_model.overwrite": lambda t, x: hbjax.save_model(t / "m.json", M, overwrite=x),
    "save_recording.overwrite": lambda t, x: hbjax.save_recording(
        t / "r.csv", hbjax.Recording(V, Y), overwrite=x),
    "identify_giri.throw": lambda t, x: hbjax.identify_giri(D, *records(), throw=x),
    "refine.throw": lambda t, x: hbjax.refine(MN, REC, throw=x),
    "separable_ls.throw": lambda t, x: hbjax.separable_ls(MN, REC, h_m=H_M, throw=x),
    "fit.throw": lambda t, x: fit(throw=x),
    "monte_carlo.keep_estimates": lambda t, x: mc(keep_estimates=x),
    "GiriDesign.check_model.assumptions": lambda t, x: D.check_model(M, assumptions=x),
    "plot.plot_backlash.sweep": lambda t, x: hbjax.plot.plot_backlash(BL, (-5, 5), sweep=x),
}


@pytest.mark.parametrize("value", ["no", "false", 0, None])
@pytest.mark.parametrize("flag", list(FLAGS))
def test_flags_must_be_bools(flag, value, tmp_path):
    if flag.startswith("plot."):
        pytest.importorskip("matplotlib").use("Agg")
        import hbjax.plot  # noqa: F401
    with pytest.raises(TypeError, match=f"`{flag.rsplit('.', 1)[1]}` must be True or False"):
        FLAGS[flag](tmp_path, value)
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_numpy_bools_are_flags(tmp_path):
    hbjax.save_model(tmp_path / "m.json", M, overwrite=np.bool_(False))
    hbjax.save_model(tmp_path / "m.json", M, overwrite=np.True_)
    D.check_model(M, assumptions=np.True_)


# ----------------------------------------------------------------------------- failure isolation


def test_monte_carlo_reports_singular_realisations_and_finishes_the_rest():
    from hbjax._identify.giri import SINGULAR_LS, estimate_giri

    def sometimes_singular(design, y1, y2, y3):
        # y1(0) = xi(0) (v1(0) = 0, zero initial conditions): where it is positive the v2
        # record is lost, the two lagged-y columns of (26) are constant and equal.
        return estimate_giri(design, y1, jnp.where(y1[0] > 0, 0.0, y2), y3)

    kw = {**MC, "key": jax.random.key(5), "keep_estimates": True}
    clean = hbjax.monte_carlo(M, D, **kw)
    mixed = hbjax.monte_carlo(M, D, estimator=sometimes_singular, **kw)
    failed = mixed.codes != 0
    assert failed.any() and (~failed).any()
    np.testing.assert_array_equal(mixed.codes[failed], SINGULAR_LS)
    np.testing.assert_array_equal(mixed.n_failed, failed.sum(axis=1))
    np.testing.assert_array_equal(mixed.n_valid, (~failed).sum(axis=1))
    ok = ~failed[0]
    np.testing.assert_allclose(mixed.mean[0], mixed.estimates[0, ok].mean(axis=0), rtol=1e-12)
    # The other realisations are untouched: the clean study's estimates.
    np.testing.assert_allclose(mixed.estimates[~failed], clean.estimates[~failed], rtol=1e-12, atol=0)
    assert np.all(np.isfinite(mixed.rmse))
    assert not np.allclose(mixed.rmse, clean.rmse, rtol=1e-12)  # computed from the rest only


def test_refine_and_fit_with_throw_false_return_a_failure_code():
    from hbjax._identify.refine import RESULTS

    with pytest.raises(hbjax.RefinementError, match="did not converge: .*pass throw=False"):
        hbjax.refine(MN, REC, h_m=H_M, max_steps=1)
    res = hbjax.refine(MN, REC, h_m=H_M, max_steps=1, throw=False)
    assert res.result != RESULTS.successful and "maximum number of steps" in res.message
    assert all(np.all(np.isfinite(leaf)) for leaf in _leaves(res.model))

    res = fit(max_steps=1, throw=False)
    assert res.result != RESULTS.successful
    assert np.all(np.asarray(res.starts_result) != 0)
    assert res.starts_costs.shape == (FIT["starts"],)


def test_a_failed_refinement_in_a_batch_leaves_the_others_intact():
    # vmapped refinement (as in Monte Carlo 'refined'): one start has mu = 0, so the
    # paper's normalisation is undefined; it reports a code, the others converge as alone
    # (to the solver's tolerance: converged members of a vmapped loop may take extra steps).
    from hbjax._identify.refine import RESULTS, refine_traceable

    quarter = hbjax.Backlash([0.0, 0.0, 1.0 / 16.0], [1.0, 0.0, 0.0])  # mu(4) = 1 - 16/16 = 0
    starts = [MN, hbjax.Hammerstein(quarter, MN.arx), hbjax.normalise(model_with(a=[-1.1, 0.4]), H_M)]
    batch = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *starts)
    recs = ((jnp.asarray(V_R), jnp.asarray(Y_R)),)
    out = jax.jit(jax.vmap(lambda m: refine_traceable(m, recs, h_m=H_M)))(batch)
    codes = np.asarray(out.result._value)
    assert codes[1] == int(RESULTS.gauge_undefined._value)
    assert codes[0] == codes[2] == int(RESULTS.successful._value)
    theta = jax.vmap(hbjax.flatten_params)(out.model)
    for i in (0, 2):
        alone = hbjax.refine(starts[i], REC, h_m=H_M)
        np.testing.assert_allclose(theta[i],
                                   hbjax.flatten_params(alone.model), rtol=1e-6, atol=1e-9)


# ----------------------------------------------------------------------------- files


def _no_temp_files(folder):
    return [p.name for p in folder.iterdir() if p.name.endswith(".tmp")] == []


@pytest.mark.parametrize("step", ["os.replace", "os.link"])
def test_interrupted_write_leaves_the_old_file_intact(tmp_path, monkeypatch, step):
    # A failure after the data are written but before the rename that publishes them.
    import os

    old_model, old_csv = model_file(tmp_path), tmp_path / "r.csv"
    hbjax.save_recording(old_csv, hbjax.Recording(V, Y))
    before = {p: p.read_bytes() for p in (old_model, old_csv)}

    def crash(*args, **kwargs):
        raise OSError("power cut between write and rename")

    monkeypatch.setattr(os, "replace", crash)
    if step == "os.link":  # (a failing link falls back to replace on file systems without links)
        monkeypatch.setattr(os, "link", crash)
    other = hbjax.normalise(M, H_M)
    with pytest.raises(OSError, match="power cut"):
        if step == "os.replace":  # overwriting goes through os.replace
            hbjax.save_model(old_model, other, overwrite=True)
        else:  # a new file is published with os.link (no clobbering in a race)
            hbjax.save_model(tmp_path / "new.json", other)
    with pytest.raises(OSError, match="power cut"):
        if step == "os.replace":
            hbjax.save_recording(old_csv, hbjax.Recording(Y, V), overwrite=True)
        else:
            hbjax.save_recording(tmp_path / "new.csv", hbjax.Recording(Y, V))
    with pytest.raises(CLIError, match="exit 1: .*power cut"):
        if step == "os.replace":
            cli("simulate", "--model", old_model, "--input", text_file(tmp_path, "v.csv", "v\n1\n"),
                "--out", old_csv, "--force")
        else:
            cli("simulate", "--model", old_model, "--input", text_file(tmp_path, "v.csv", "v\n1\n"),
                "--out", tmp_path / "new2.csv")
    monkeypatch.undo()
    assert {p: p.read_bytes() for p in before} == before
    assert not (tmp_path / "new.json").exists() and not (tmp_path / "new.csv").exists()
    assert not (tmp_path / "new2.csv").exists()
    assert _no_temp_files(tmp_path)
    assert hbjax.load_model(old_model).arx.b.tobytes() == M.arx.b.tobytes()


def test_every_truncation_of_a_model_file_is_refused_clearly(tmp_path):
    text = model_file(tmp_path).read_text()
    cuts = sorted(set(np.linspace(0, len(text) - 2, 80).astype(int)))
    for cut in cuts:
        p = text_file(tmp_path, "cut.json", text[:cut])
        with pytest.raises(ModelFileError) as info:
            hbjax.load_model(p)
        assert str(p) in str(info.value), (cut, str(info.value))


def test_edited_model_files_load_correctly_or_are_refused_clearly(tmp_path):
    # Random one-character edits: either a valid model comes back (e.g. a digit changed),
    # or a ModelFileError naming the file; never another exception, never NaN coefficients.
    text = model_file(tmp_path).read_text()
    rng = np.random.default_rng(11)
    alphabet = list('0123456789.-+eE"{}[],: abcnull')
    outcomes = Counter()
    for _ in range(300):
        i = int(rng.integers(len(text)))
        edited = text[:i] + str(rng.choice(alphabet)) + text[i + 1:]
        p = text_file(tmp_path, "edit.json", edited)
        try:
            model = hbjax.load_model(p)
        except ModelFileError as exc:
            assert str(p) in str(exc)
            outcomes["refused"] += 1
            continue
        assert isinstance(model, hbjax.Hammerstein)
        for leaf in jax.tree_util.tree_leaves(model):
            assert leaf.dtype == np.float64 and leaf.ndim == 1 and np.all(np.isfinite(leaf))
        assert model.backlash.c1.shape == model.backlash.c2.shape
        outcomes["loaded"] += 1
    assert outcomes["refused"] > 50 and outcomes["loaded"] > 10


# ----------------------------------------------------------------------------- the README table


def coverage_counts() -> tuple[Counter, int, int]:
    return Counter(c.kind for c in CASES), len(PROMOTED), len(TRACED)


def coverage_markdown() -> str:
    kinds, promoted, traced = coverage_counts()
    gaps = Counter(c.kind for c in CASES if c.xfail)
    targets: dict[str, set] = {}
    for c in CASES:
        name = "CLI" if c.target.startswith("hbjax") else c.target.split(".")[0]
        targets.setdefault(c.kind, set()).add(name)
    lines = ["| bad-input class | cases | of which open (xfail) | entry points |",
             "|---|---:|---:|---|"]
    for kind, n in kinds.items():
        lines.append(f"| {kind} | {n} | {gaps[kind]} | {', '.join(sorted(targets[kind]))} |")
    lines.append(f"| **total** | **{sum(kinds.values())}** | **{sum(gaps.values())}** | |")
    lines += [
        "",
        f"Accepted and promoted to float64 (result bitwise equal to the float64 call): "
        f"{promoted} cases. Value checks inside `jax.jit`, `eqx.filter_jit` and `jax.vmap` "
        f"(`eqx.error_if`, message kept): {traced} checks x 3 transforms.",
    ]
    return "\n".join(lines)


README = pathlib.Path(__file__).with_name("README.md")
BEGIN, END = "<!-- robustness-table:begin -->", "<!-- robustness-table:end -->"


def test_readme_counts_are_current():
    text = README.read_text()
    assert BEGIN in text and END in text
    current = text.split(BEGIN)[1].split(END)[0].strip()
    assert current == coverage_markdown(), "run `python tests/test_robustness.py` to update"


def _write_readme():
    text = README.read_text()
    head, rest = text.split(BEGIN)
    _, tail = rest.split(END)
    README.write_text(f"{head}{BEGIN}\n{coverage_markdown()}\n{END}{tail}")


if __name__ == "__main__":
    sys.exit(_write_readme())


def test_bfloat16_inputs_are_numeric():
    """An ML float type NumPy does not class as a number (bfloat16) is a float input: the
    simulation runs in the promoted dtype (it was refused as "not numeric")."""
    m32 = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), M)
    v = np.linspace(-5.0, 5.0, 50)
    for x in (v.astype(jnp.bfloat16), jnp.asarray(v, jnp.bfloat16)):
        y = hbjax.simulate(m32, x)
        assert y.dtype == jnp.float32
        np.testing.assert_allclose(y, hbjax.simulate(m32, np.asarray(x, np.float32)), rtol=1e-6)
