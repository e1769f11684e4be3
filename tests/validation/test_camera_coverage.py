"""Coverage of the camera's intervals over simulated boards with the measured structure
(slow): the view-systematic model against plain least squares."""

import numpy as np
import pytest
from scipy.stats import binom

from bayescal.validation.camera_cv import camera_coverage

MEASURED = {"n_views": 8, "view_field": 0.15, "column_error": 0.25}


@pytest.mark.slow
def test_coverage_of_the_view_systematic_model():
    """30 replications, 90 % intervals: each intrinsic's count must reach the binomial
    0.5 % quantile of Bin(30, 0.9) (false failure <= 2.5 % over the five); plain least
    squares is reported beside it, not asserted."""
    n = 30
    lo = binom.ppf(0.005, n, 0.9)
    cov = camera_coverage(n, rng=7, simulate=MEASURED)
    assert np.all(cov["hits"] >= lo), cov["hits"]
    plain = camera_coverage(n, rng=7, simulate=MEASURED, noise="plain")
    print("view-systematic", cov["hits"], "plain", plain["hits"])
