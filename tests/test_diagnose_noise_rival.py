"""The rule that reports a mechanism on its held-out one-step prediction gain where a noise
model could mimic that gain in prediction (`noise_rival`): it must beat that noise model by
the BIC margin, gain significantly in held-out prediction over its reference and the
nominal model, and not simulate significantly worse than its reference or the nominal
model."""

import types

import pytest

import hbjax
from hbjax._diagnose.decide import BIC_MARGIN, DM_Z, _margin_over_noise_rival

RIVALLED = [name for name, cls in hbjax.EFFECTS.items() if cls.noise_rival is not None]


def test_dynamics_effects_name_the_noise_model_that_mimics_them_in_prediction():
    # each changes the input-to-output dynamics inside the loop, and each gains in one-step
    # prediction as an AR noise model does; nothing else may take the prediction-only path
    assert sorted(RIVALLED) == ["coulomb_friction", "level_dependent_dynamics",
                                "unmodeled_dynamics"]
    assert all(hbjax.EFFECTS[n].noise_rival == "colored_noise" for n in RIVALLED)


@pytest.mark.parametrize("effect", RIVALLED)
def test_prediction_gain_counts_only_past_the_noise_model_by_the_margin(effect):
    cls = hbjax.EFFECTS[effect]
    candidate = types.SimpleNamespace(cls=cls, anchored=False, effect=effect, label=effect)
    names = [effect, "colored_noise"]
    nominal, reference = {"fit_pred": 90.0}, {"fit_pred": 92.0}

    def margin(own_bic=-1000.0, rival_bic=-1000.0 + BIC_MARGIN + 5, dm=0.5, dm_pred=DM_Z + 1,
               fit_pred=93.0, dm_sim_nom=0.3):
        own = {"bic": own_bic, "fit_pred": fit_pred}
        stats = [nominal, own, {"bic": rival_bic}]
        return _margin_over_noise_rival(candidate, own, stats, names, dm, dm_pred, reference,
                                        nominal, dm_sim_nom)

    assert margin() == pytest.approx(BIC_MARGIN + 5)
    assert margin(rival_bic=-1000.0 + BIC_MARGIN - 1) is None      # the noise model does as well
    assert margin(dm_pred=DM_Z - 0.1) is None                      # no significant prediction gain
    assert margin(dm=-DM_Z - 0.1) is None                          # free run significantly worse
    assert margin(dm_sim_nom=-DM_Z - 0.1) is None                  # ... than the nominal model's
    assert margin(fit_pred=91.0) is None                           # not above its reference
    assert margin(rival_bic=float("nan")) is None                  # a failed rival proves nothing
