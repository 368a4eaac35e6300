"""The agent models are one table (fxc_env.core.models.AGENT_MODELS): the names, their parameters, the fxc flags and
the matrices are read from it."""

from __future__ import annotations

import numpy as np
import pytest

from fxc_env.config.flags import MODEL_FLAGS
from fxc_env.core.models import AGENT_MODELS, MODEL_NAMES, MODEL_PARAMETERS, model_matrices, model_spec
from fxc_env.core.validation import ArgumentError


def test_names_parameters_and_flags_come_from_the_table():
    assert MODEL_NAMES == tuple(AGENT_MODELS)
    assert MODEL_PARAMETERS == {"integrator_chain": "order", "damped": "damping", "oscillator": "frequency"}
    assert set(MODEL_FLAGS) == set(MODEL_PARAMETERS.values())
    for model in AGENT_MODELS.values():
        if model.parameter:
            assert MODEL_FLAGS[model.parameter] == (model.flag_type, model.flag_help)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_each_model_builds_its_matrices_and_its_parameter_is_its_own(name):
    A, B = model_matrices(name)
    assert A.shape == (A.shape[0], A.shape[0]) and B.shape == (A.shape[0], 1) and B[-1, 0] == 1.0
    np.testing.assert_array_equal(A, AGENT_MODELS[name].matrices(None)[0])
    for parameter, owner in ((p, o) for o, p in MODEL_PARAMETERS.items() if o != name):
        with pytest.raises(ArgumentError, match=rf"^{parameter}: only agent_model = '{owner}' has a {parameter}"):
            model_matrices(name, **{parameter: 2})
    assert model_spec({"name": name}) == (name, {})
