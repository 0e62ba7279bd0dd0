"""Numerical precision policy.

Identification solves least-squares and Vandermonde systems whose accuracy float32 cannot
carry, so the estimators need JAX's 64-bit mode. Importing :mod:`hbjax` changes no global
setting: the user enables it (``jax.config.update("jax_enable_x64", True)``, once, at the
start of the program) and each estimator checks. The simulator (``simulate``, ``predict``,
``play``) computes in the dtype it is given, so float32 pipelines stay float32.
"""

import jax


def require_x64(where: str) -> None:
    """Raise one clear line if JAX's 64-bit mode is off (estimators never run in float32)."""
    if not jax.config.read("jax_enable_x64"):
        raise RuntimeError(
            f"{where} needs float64: call jax.config.update('jax_enable_x64', True) at the start "
            "of your program, before creating any array."
        )
