"""The point draws' closed-form Cholesky factor of the inverse precision."""

import numpy as np
import pytest

from bayescal.likelihood.point_draws import chol_of_inverse


@pytest.mark.parametrize("k", [1, 2, 3])
def test_chol_of_inverse_matches_numpy(k):
    rng = np.random.default_rng(0)
    A = rng.normal(size=(5, 7, k, k))
    C = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(k)
    ref = np.linalg.cholesky(np.linalg.inv(C))
    # rounding only: the closed form and LAPACK agree to ~1e-12 relative
    np.testing.assert_allclose(chol_of_inverse(C), ref, rtol=1e-9, atol=1e-12)


def test_chol_of_inverse_is_nan_where_not_positive_definite():
    C = np.array([[[1.0, 2.0], [2.0, 1.0]]])             # indefinite
    assert np.all(np.isnan(chol_of_inverse(C)[0, 1, 1]))
