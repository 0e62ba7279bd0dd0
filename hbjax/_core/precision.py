"""Numerical precision policy.

Identification solves least-squares and Vandermonde systems whose accuracy float32
cannot carry, so importing :mod:`hbjax` enables JAX's 64-bit mode
(``jax_enable_x64``). Every array the package creates is float64; integer and float32
inputs are promoted to float64.
"""

import jax


jax.config.update("jax_enable_x64", True)


def require_x64(where: str) -> None:
    """Raise if 64-bit mode was switched off after import (never compute in float32)."""
    if not jax.config.read("jax_enable_x64"):
        raise RuntimeError(
            f"{where} needs float64: hbjax enables `jax_enable_x64` on import; "
            "re-enable it with jax.config.update('jax_enable_x64', True)."
        )
