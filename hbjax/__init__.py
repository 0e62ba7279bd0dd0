"""hbjax: identification of Hammerstein systems with a hysteresis-backlash input
nonlinearity (Giri et al.), in JAX."""

from ._core.arx import ARX as ARX
from ._core.backlash import Backlash as Backlash
from ._core.defaults import default_design as default_design, default_system as default_system
from ._identify.giri import GiriResult as GiriResult, identify_giri as identify_giri, normalise as normalise
from ._core.model import AbstractModel as AbstractModel, Hammerstein as Hammerstein
from ._results import RESULTS as RESULTS
from ._core.params import (
    flatten_params as flatten_params,
    param_names as param_names,
    unflatten_params as unflatten_params,
)
from ._core.signals import GiriDesign as GiriDesign
from ._core.simulate import play as play, predict as predict, simulate as simulate
from ._core.cache import compilation_cache_dir as compilation_cache_dir

# --- refinement (issue 3) ---
from ._identify.crlb import CRLBResult as CRLBResult, crlb as crlb
from ._identify.fit import FitResult as FitResult, fit as fit, normalise_static_gain as normalise_static_gain
from ._identify.refine import RefineResult as RefineResult, RefinementError as RefinementError, refine as refine
from ._identify.separable import separable_ls as separable_ls
# --- validation: initial state, compare, resid, structure selection ---
from ._core.initial import InitialState as InitialState, estimate_initial_state as estimate_initial_state
from ._identify.compare import Comparison as Comparison, compare as compare
from ._identify.residual_analysis import ResidualAnalysis as ResidualAnalysis, resid as resid
from ._identify.structure import StructureSelection as StructureSelection, select_structure as select_structure
# --- monte carlo (issue 4) ---
from ._montecarlo.run import Study as Study, monte_carlo as monte_carlo
# --- diagnosis (issue 5) ---
from ._diagnose.concealed import ConcealedRecording as ConcealedRecording, concealed_recording as concealed_recording
from ._diagnose.nominal import identify_nominal as identify_nominal
from ._diagnose.residual_tests import fit_percent as fit_percent
from ._diagnose.diagnose import Diagnosis as Diagnosis, Finding as Finding, diagnose as diagnose
from ._diagnose.effects import EFFECTS as EFFECTS
from ._diagnose.effect_base import AbstractEffect as AbstractEffect
from ._diagnose.effect_base import EffectConstraint as EffectConstraint
# --- io, datasets, cli (issue 6) ---
from . import datasets as datasets, internal as internal
from ._io.recording import (
    Recording as Recording,
    load_recording as load_recording,
    save_recording as save_recording,
)
from ._io.modelfile import (
    ModelFileError as ModelFileError,
    load_model as load_model,
    save_model as save_model,
)

__version__ = "0.1.0"


def __getattr__(name):
    # `hbjax.plot` works after a plain `import hbjax`, but matplotlib is loaded only on first use.
    if name == "plot":
        import importlib

        return importlib.import_module(".plot", __name__)
    raise AttributeError(f"module 'hbjax' has no attribute {name!r}")
