"""Shared fixtures: a non-interactive matplotlib backend, a seeded ``rng``,
a few sensors that differ from the paper's in every parameter, and a
central finite-difference helper for checking analytic Jacobians."""

import matplotlib

matplotlib.use("agg")  # before anything imports pyplot

import numpy as np  # noqa: E402
import pytest  # noqa: E402

import bayescal as bc  # noqa: E402

SEED = 20231121

# Parameter sets for model tests. Every set keeps cos(beta) < xi so that all
# points of the lit cone are inside the projection domain (xi * r - z > 0).
SENSORS = {
    "paper": bc.SensorParams.paper(),
    "xi0.8_phi0.3": bc.SensorParams(xi=0.8, phi=0.3, alpha_u=62.0, alpha_v=-48.0,
                                    u0=410.0, v0=290.0, h=160.0, beta=1.1),
    "xi0.6_phi1.1": bc.SensorParams(xi=0.6, phi=1.1, alpha_u=31.0, alpha_v=-35.0,
                                    u0=322.5, v0=241.0, h=260.0, beta=1.25),
    "xi1_phi-0.2_av+": bc.SensorParams(xi=1.0, phi=-0.2, alpha_u=70.0, alpha_v=66.0,
                                       u0=640.0, v0=480.0, h=120.0, beta=0.95),
}


@pytest.fixture
def rng():
    """A fresh generator with a fixed seed (tests are reproducible)."""
    return np.random.default_rng(SEED)


@pytest.fixture(params=list(SENSORS), ids=list(SENSORS))
def sensor(request):
    """One of :data:`SENSORS` (tests using it run once per sensor)."""
    return SENSORS[request.param]


def _numdiff(f, x, step):
    """Central differences of ``f: (..., n) -> (..., m)``; returns ``(..., m, n)``.

    ``step`` is a scalar or a length-``n`` sequence of absolute steps.
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    step = np.broadcast_to(np.asarray(step, dtype=float), (n,))
    cols = []
    for i in range(n):
        dx = np.zeros(n)
        dx[i] = step[i]
        cols.append((np.asarray(f(x + dx)) - np.asarray(f(x - dx))) / (2 * step[i]))
    return np.stack(cols, axis=-1)


@pytest.fixture
def numdiff():
    """The central finite-difference helper ``numdiff(f, x, step)``."""
    return _numdiff
