"""The result of :func:`hbjax.diagnose`: one :class:`Finding` per diagnosed effect and the
:class:`Diagnosis` that holds them with the residual tests, the candidate table and the
verdict."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np

from .._core import display
from .._core.model import Hammerstein
from .._misc import jsonable as _jsonable
from . import verdict as vd


@dataclasses.dataclass(frozen=True)
class Finding:
    """One diagnosed effect. Fits are held-out fits in percent,
    ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)``, in the given ``metric``
    (``"simulation"``: free run; ``"prediction"``: one step ahead)."""

    effect: str
    physics: str
    where: dict
    parameters: dict
    model: object
    metric: str
    fit_before: float
    fit_after: float
    evidence: dict

    @property
    def mechanism(self) -> bool:
        """A physical mechanism (``evidence["kind"]``), not a noise model."""
        return self.evidence.get("kind", "mechanism") == "mechanism"

    def to_dict(self) -> dict:
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "model"}
        d["model_class"] = type(self.model).__name__
        return _jsonable(d)


@dataclasses.dataclass(frozen=True)
class Diagnosis:
    """Result of :func:`diagnose`: ``findings`` (most supported first), ``best`` (the first
    or ``None``), ``mismatch`` and the residual tests of the nominal model.

    ``verdict`` says one of three things: ``"consistent"`` (no finding and the residual
    tests pass), ``"explained"`` (a finding), ``"unexplained"`` (no finding but whiteness
    or independence rejected; ``unexplained`` then names the rejecting tests and the regime
    variable that explains most of the residual). ``failed`` maps candidates whose fit
    ended at non-finite numbers to the reason; ``unconverged`` names the candidates whose
    solver stopped at its step limit before converging (judged where they stopped: each
    Levenberg-Marquardt step lowers the fitting criterion, so a converged fit would only
    fit the fitting part better). ``split`` reports where the record was cut into its
    fitting and held-out parts and how excited each is."""

    mismatch: bool
    findings: list
    residual_tests: dict
    candidates: dict
    n_fit: int
    n_holdout: int
    nominal: Hammerstein = dataclasses.field(repr=False, default=None)
    v: np.ndarray = dataclasses.field(repr=False, default=None)
    y: np.ndarray = dataclasses.field(repr=False, default=None)
    dt: float | None = dataclasses.field(repr=False, default=None)
    # the recording's first sample time (a Recording's t0), for the figure's time axis
    t0: float = dataclasses.field(repr=False, default=0.0)
    verdict: str = "consistent"
    unexplained: dict = dataclasses.field(default_factory=dict)
    failed: dict = dataclasses.field(default_factory=dict)
    split: dict = dataclasses.field(default_factory=dict)

    @property
    def best(self):
        return self.findings[0] if self.findings else None

    @property
    def unconverged(self) -> tuple:
        """Candidates whose fit stopped at the solver's step limit without converging
        (``candidates[name]["lm_converged"]`` is False), failed ones excepted."""
        return tuple(k for k, c in self.candidates.items()
                     if c.get("lm_converged") is False and k not in self.failed)

    def summary(self) -> display.Summary:
        """The residual tests and the findings with their held-out fits: a text that
        renders as HTML tables in Jupyter."""
        lines = [f"Mismatch diagnosis: {self.n_fit} samples fitted, {self.n_holdout} held out."]
        w = self.residual_tests["whiteness"]
        ind = self.residual_tests["independence"]
        lines.append(
            f"Nominal residuals: whiteness p = {_num(w['p_value'])} ({w['lags_outside']} lags "
            f"outside the 99% band); independence from the past {ind.get('against', 'input')} p = "
            f"{_num(ind['p_value'])}.")
        lines.append(vd.sentence(self.verdict, self.unexplained, self.findings))
        if self.split.get("moved"):
            lines.append(f"Held-out part moved earlier to {self.n_holdout} samples: the "
                         f"requested tail was less excited than the fitting part (excitation "
                         f"ratio {self.split['requested_ratio']['ratio']:.2f} -> "
                         f"{self.split['ratio']['ratio']:.2f}).")
        if skipped := self.split.get("skipped_for_error"):
            cuts = f"{len(skipped)} earlier cut{'s' * (len(skipped) > 1)}"
            lines.append(
                f"{cuts} not taken although the held-out part is less "
                f"excited (ratio {self.split['ratio']['ratio']:.2f}): they would have moved the "
                f"nominal model's misfit out of the fitting part (held-out/fitting mean squared "
                f"free-run error up to {max(s['error_ratio'] for s in skipped):.1f}, limit "
                f"{self.split['error_limit']:.1f}).")
        if self.failed:
            lines.append("Failed candidates: " + "; ".join(
                f"{k} ({why})" for k, why in self.failed.items()))
        if self.unconverged:
            steps = max(int(self.candidates[k].get("lm_steps") or 0) for k in self.unconverged)
            lines.append(f"Stopped at the solver's step limit ({steps} steps) before converging, "
                         "judged where they stopped: " + ", ".join(self.unconverged) + ".")
        head = list(lines)
        for i, f in enumerate(self.findings, 1):
            lines.append(f"{i}. {f.effect}: {f.physics}")
            lines.append(f"   where: {_short(f.where)}")
            lines.append(f"   parameters: {_short(f.parameters)}")
            vs = "nominal" if f.evidence.get("reference") == "nominal" else "refit"
            lines.append(f"   held-out {f.metric} fit {f.fit_before:.1f}% -> {f.fit_after:.1f}% "
                         f"(dBIC vs {vs} {_num(f.evidence.get(f'delta_bic_vs_{vs}'), '.1f')}, "
                         f"DM z {_num(f.evidence.get('dm_z'), '.1f')})")
            if "variant" in f.evidence:
                lines.append(f"   ({f.evidence['variant']})")
        tables = [display.findings_table(self.findings)] if self.findings else []
        notes = head[1:] + [f"{i}. {f.effect}: {f.physics}" for i, f in enumerate(self.findings, 1)]
        html = display.report(head[0], tables=tables, notes=notes)._repr_html_()
        return display.Summary("\n".join(lines), html)

    def __repr__(self) -> str:
        best = self.best.effect if self.best else None
        return (f"Diagnosis(verdict={self.verdict!r}, best={best!r}, findings="
                f"{[f.effect for f in self.findings]}, n_fit={self.n_fit}, "
                f"n_holdout={self.n_holdout})")

    def _repr_html_(self) -> str:
        return self.summary()._repr_html_()

    def to_dict(self) -> dict:
        return _jsonable({
            "mismatch": self.mismatch,
            "verdict": self.verdict,
            "unexplained": self.unexplained,
            "failed": self.failed,
            "unconverged": list(self.unconverged),
            "split": self.split,
            "best": self.best.effect if self.best else None,
            "findings": [f.to_dict() for f in self.findings],
            "residual_tests": self.residual_tests,
            "candidates": self.candidates,
            "n_fit": self.n_fit, "n_holdout": self.n_holdout,
        })


def _num(x, spec=".3g"):
    return "n/a" if x is None or not math.isfinite(float(x)) else format(float(x), spec)


def _short(d):
    return json.dumps(_jsonable(d))[:300]


def _num(x, spec=".3g"):
    return "n/a" if x is None or not math.isfinite(float(x)) else format(float(x), spec)


def _short(d):
    return json.dumps(_jsonable(d))[:300]
