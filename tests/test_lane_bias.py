"""The lanes' estimated biases (:class:`fgloc.registration.lane_bias.LaneBiases`)."""

import numpy as np
import pytest

from fgloc.registration.lane_bias import LaneBiases


def test_free_params_count_the_biases_the_data_fix():
    """A bias the data fix (variance far below the prior's) counts as one parameter, one only
    its prior holds (variance the prior's) as none: 2 lanes of data precision 1e6 and 1e-6
    (1/m^2) under a 0.1 m prior count about 1."""
    prior = 1.0 / 0.1**2
    info = np.diag([50.0, 1e6 + prior, 1e-6 + prior])
    variance = np.diag(np.linalg.inv(info))[1:]
    assert LaneBiases(0.1).free_params(variance) == pytest.approx(1.0, abs=1e-3)
