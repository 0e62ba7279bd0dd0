"""Semi-public cores for users who jit, vmap or batch the estimators themselves.

As ``optimistix.internal``: stable enough to build on, but with fewer guarantees than the
top-level names. They never raise on bad data: each returns its result code in ``.result``.

- :func:`estimate_giri`: the closed form of sections 4-5 (eqs. (26), (45)-(46)) as a pure
  function of three output records; what :func:`hbjax.monte_carlo` vmaps.
- :func:`refine_traceable`, :func:`refine_batch`: the prediction/output-error refinement
  (eq. (10)) on tuples of ``(v, y)`` arrays, and a compiled batch over noise realisations.
- :func:`separable_traceable`: the variable-projection baseline.
- :func:`plateaus`: the runs of a record stuck at its extreme (sensor or actuator clip).
- :data:`CONCEALED_INPUTS`: the input kinds :func:`hbjax.concealed_recording` accepts.
"""

from ._diagnose.concealed import INPUTS as CONCEALED_INPUTS
from ._diagnose.residual_tests import plateaus as plateaus
from ._identify.giri import estimate_giri as estimate_giri
from ._identify.refine import refine_batch as refine_batch, refine_traceable as refine_traceable
from ._identify.separable import separable_traceable as separable_traceable

__all__ = [
    "CONCEALED_INPUTS",
    "estimate_giri",
    "plateaus",
    "refine_batch",
    "refine_traceable",
    "separable_traceable",
]
