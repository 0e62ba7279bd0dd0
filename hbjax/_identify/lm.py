"""The one Levenberg-Marquardt set-up of the package (``optimistix.least_squares``):
refinement (:mod:`hbjax._identify.refine_solve`) and the diagnosis's fits
(:mod:`hbjax._diagnose.solve`, nominal identification included) call it with their
residual, their tolerances and, where they have one, a hand-written Jacobian.
"""

import jax
import lineax as lx
import optimistix as optx


def levenberg_marquardt(fn, x0, args=None, *, max_steps: int, rtol: float, atol: float,
                        norm=None, normal_cholesky: bool = False, jac=None):
    """Minimise ``sum fn(x, args)^2`` from ``x0``; returns the ``optimistix.Solution``
    (``throw=False``: the caller reads ``sol.result``; never raises).

    ``norm``: the convergence norm (optimistix's default RMS norm when ``None``);
    ``normal_cholesky``: solve each step's linear problem by Cholesky on the normal
    equations (refinement: few parameters, many residuals) instead of optimistix's
    default QR. ``jac(x, args)``: the Jacobian of ``fn`` as a dense matrix, handed to
    the solver through a ``custom_jvp``: the solver linearises the residual and
    applies/transposes that linear map many times per step; a JVP that materialises the
    Jacobian once makes those products dense matmuls (cheaper to run and much cheaper to
    compile than linearising and transposing the criterion).
    """
    options = {} if norm is None else {"norm": norm}
    if normal_cholesky:
        options["linear_solver"] = lx.Normal(lx.Cholesky())
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol, **options)
    if jac is not None:
        fn = _with_jacobian(fn, jac, args)
    return optx.least_squares(fn, solver, x0, args=args, max_steps=max_steps, throw=False)


def _with_jacobian(fn, jac, args):
    @jax.custom_jvp
    def resid(x):
        return fn(x, args)

    @resid.defjvp
    def _jvp(primals, tangents):
        return fn(primals[0], args), jac(primals[0], args) @ tangents[0]

    return lambda x, _: resid(x)
