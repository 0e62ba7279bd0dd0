"""The main job (``make demo`` / ``hbjax demo``): simulate the default system, run the
paper's three experiments, identify it, and report."""

import os
import time
from pathlib import Path

import jax
import numpy as np

from .._core.defaults import default_design, default_system
from .._misc import check_bool, positive_float, positive_int
from .._io.files import atomic_write_many, check_writable
from .._identify.giri import identify_giri, normalise
from .._core.params import flatten_params, param_names
from .._identify.refine import refine
from .._core.simulate import simulate


def _table(names, truth, closed, refined, std) -> str:
    rows = [f"{'parameter':>10} {'true (normalised)':>18} {'closed form':>12} {'error':>10}"
            f" {'refined':>12} {'error':>10} {'std. error':>10}"]
    for name, t, c, r, s in zip(names, truth, closed, refined, std):
        rows.append(f"{name:>10} {t:18.6f} {c:12.6f} {c - t:10.2e} {r:12.6f} {r - t:10.2e} {s:10.2e}")
    return "\n".join(rows)


FIGURES = ("backlash_loop.png", "v3_and_u.png", "measured_vs_simulated.png")


def _missing_folders(out: Path) -> list[Path]:
    """The folders of ``out`` still to create, outermost first; ``out`` and whatever of its
    path exists must be folders the demo can write into."""
    missing, p = [], out
    while not os.path.lexists(p) and p != p.parent:
        missing.append(p)
        p = p.parent
    if not p.is_dir():
        where = "" if p == out else f": {str(p)!r} in its path is not a folder"
        raise NotADirectoryError(f"`out` must be a folder, got {str(out)!r}{where}.")
    if not os.access(p, os.W_OK | os.X_OK):
        raise PermissionError(f"`out` {str(out)!r}: no permission to write into {str(p)!r}.")
    return missing[::-1]


def _check_demo_outputs(out: Path, force: bool) -> list[Path]:
    """Refuse, before any work, every figure that could not be written; returns the folders
    to create."""
    missing = _missing_folders(out)
    if not missing:  # in a new folder no figure can be in the way
        for name in FIGURES:
            try:
                check_writable(out / name, overwrite=force, hint="--force")
            except (OSError, ValueError) as exc:
                raise type(exc)(f"`out`: {exc}") from None
    return missing


def run_demo(out="demo_output", *, force=False, n_samples=10_000, noise_std=0.5, seed=0):
    """Run the demo, print the table and write figures into ``out``; returns the
    closed-form :class:`hbjax.GiriResult` and the :class:`hbjax.RefineResult`.

    Arguments and outputs are checked before any work: ``out`` must be a folder (created if
    missing), ``n_samples`` at least one period of the staircase ``v3`` and the figures
    (:data:`FIGURES`) new unless ``force``. They are written together at the end (all or
    nothing); if the run fails, the folders it created are removed again."""
    design = default_design()
    # The longest of the design's minimum records: one period of the staircase v3.
    n_samples = positive_int(n_samples, "n_samples",
                             minimum=max(design.binary_period, design.staircase_period))
    noise_std = positive_float(noise_std, "noise_std", allow_zero=True)
    seed = positive_int(seed, "seed", minimum=0)  # numpy's generator takes no negative seed
    force = check_bool(force, "force")
    out = Path(out)
    created = _check_demo_outputs(out, force)
    out.mkdir(parents=True, exist_ok=True)
    try:
        return _run(out, force, n_samples, noise_std, seed)
    except BaseException:
        for folder in reversed(created):  # innermost first; only if left empty
            try:
                folder.rmdir()
            except OSError:
                break
        raise


def _run(out: Path, force: bool, n_samples: int, noise_std: float, seed: int):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._plot.core import plot_backlash, plot_output, plot_staircase
    from .commands import _figure_bytes

    start = time.perf_counter()
    model, design = default_system(), default_design()
    keys = jax.random.split(jax.random.PRNGKey(seed), 4)
    inputs = (design.constant_input(n_samples), design.binary_input(n_samples),
              design.staircase_input(n_samples))
    ys = [simulate(model, v, noise_std * jax.random.normal(k, (n_samples,)))
          for v, k in zip(inputs, keys)]
    result = identify_giri(design, *ys)
    truth = normalise(model, design.h_m)
    estimate = result.model
    # The closed form's branch coefficients are extrapolated from the staircase levels in
    # [h_m, 2 h_m] (eqs. (45)-(46)) and are noisy; refinement on the same three records
    # (prediction error, paper normalisation) brings them to the statistical limit.
    refined = refine(estimate, list(zip(inputs, ys)), h_m=design.h_m)
    print(f"hbjax demo: default system n={design.n}, m={design.m}, h_m={design.h_m:g}, "
          f"{n_samples} samples per experiment, equation-error noise std {noise_std}")
    print(_table(param_names(truth), np.asarray(flatten_params(truth)),
                 np.asarray(flatten_params(estimate)), np.asarray(flatten_params(refined.model)),
                 np.asarray(refined.std)))
    print(f"offset ybar1 = {float(result.offset):.4f} (transient discarded: {int(result.transient)} samples); "
          f"cond(LS) = {float(result.cond_ls):.3g}; cond(Vandermonde) raw/scaled = "
          f"{float(result.cond_vandermonde[0]):.3g}/{float(result.cond_vandermonde[1]):.3g}; "
          f"gap check P2*(-h_m)-P1*(h_m) = {float(result.gap):.4f} (1 expected)")

    figures = []  # in the order of FIGURES, written together at the end
    fig, ax = plt.subplots(figsize=(5, 4), layout="constrained")
    lim = (-2 * design.h_m, 2 * design.h_m)
    plot_backlash(truth.backlash, lim, ax=ax, label="true", color="k")
    plot_backlash(estimate.backlash, lim, ax=ax, label="closed form", color="C3")
    plot_backlash(refined.model.backlash, lim, ax=ax, label="refined", color="C0")
    ax.set_title("Normalised backlash: true vs estimated")
    figures.append(fig)
    fig, axes = plt.subplots(2, 1, figsize=(7, 5), sharex=True, layout="constrained")
    plot_staircase(design, truth.backlash, axes=axes)
    figures.append(fig)
    # Validation on a fresh random-level record the estimator never saw.
    rng = np.random.default_rng(seed + 1)
    levels = rng.uniform(-2 * design.h_m, 2 * design.h_m, 100)
    v_val = np.repeat(levels, 20)
    y_val = simulate(model, v_val, noise_std * jax.random.normal(keys[3], v_val.shape))
    y_sim = simulate(estimate, v_val)
    y_ref = simulate(refined.model, v_val)
    fit, fit_ref = (100 * (1 - np.linalg.norm(y_val - y) / np.linalg.norm(y_val - np.mean(y_val)))
                    for y in (y_sim, y_ref))
    fig, ax = plt.subplots(figsize=(8, 3.5), layout="constrained")
    plot_output(y_val, y_sim, ax=ax, window=(0, 600),
                labels=("measured", f"closed form (fit {fit:.1f}%)"))
    ax.plot(np.arange(600), np.asarray(y_ref)[:600], lw=1, ls=":",
            label=f"refined (fit {fit_ref:.1f}%)")
    ax.legend(fontsize=8)
    ax.set_title("Validation record: measured vs simulated")
    figures.append(fig)
    items = [(out / name, _figure_bytes(f, name)) for name, f in zip(FIGURES, figures)]
    plt.close("all")
    atomic_write_many(items, overwrite=force, hint="--force")
    print(f"refinement: {refined.message}, {int(refined.stats['steps'])} steps; validation fit "
          f"(random-level input, free run): closed form {fit:.2f}%, refined {fit_ref:.2f}%")
    print(f"figures written to {out.resolve()}/ ({', '.join(FIGURES)}) in "
          f"{time.perf_counter() - start:.1f} s")
    return result, refined
