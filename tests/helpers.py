"""Helpers shared by tests in several folders (``tests/`` is on ``sys.path`` through
``conftest.py``, so test modules import this as ``helpers``)."""

import contextlib
import io
import os
import types
import warnings

import numpy as np


def gross_plan_pixels(ds, i, kind):
    """Pixels of ``ds`` with point ``i`` grossly wrong: its pixel moved 30 px, or the laser
    point 40 % beyond its wall (same azimuth, its pixel's noise kept)."""
    from bayescal.scene.floorplan import plan_point
    from bayescal.sensor.camera import project_theta

    pix = ds.pixels.copy()
    if kind == "pixel":
        pix[i, 1] += 30.0
        return pix
    theta, P = ds.params.to_identifiable(), ds.points[i]
    t, rho = np.arctan2(P[1], P[0]), np.hypot(P[0], P[1])
    Q = plan_point(theta, np.array([t]), np.array([1.4 * rho]), np.array([t]))
    pix[i] = project_theta(theta, Q)[0][0] + ds.pixels[i] - project_theta(theta, P[None])[0][0]
    return pix


def check_seed_scatter(means, errs):
    """Is a chain's ESS honest? ``means`` and ``errs`` (seeds, k): each sampler seed's
    posterior means and claimed Monte-Carlo errors ``sd / sqrt(ESS)``. The sd of the means
    over the rms claimed error follows ``sqrt(chi2_(m-1) / (m-1))`` per coordinate if the
    ESS is right: each coordinate inside the family-wise band (1 - 1e-3 over k), and the
    mean square inside the 99 % band (the fully correlated, widest null). Returns the ratios.
    """
    from scipy import stats

    m, k = np.shape(means)
    ratio = np.std(means, axis=0, ddof=1) / np.sqrt(np.mean(np.square(errs), axis=0))
    print(np.round(ratio, 2))
    p = 1e-3 / k / 2
    lo, hi = np.sqrt(stats.chi2(m - 1).ppf([p, 1 - p]) / (m - 1))
    assert np.all((ratio > lo) & (ratio < hi)), ratio
    pooled = np.mean(ratio**2)
    band = stats.chi2(m - 1).ppf([0.005, 0.995]) / (m - 1)
    assert band[0] < pooled < band[1], pooled
    return ratio


def check_plan_residual_jacobians(lik, g, walls, t, sigma, numdiff, *, rows, dt_tol):
    """The floor-plan least squares' Jacobians (azimuth, geometry ``g``, walls at points
    ``rows``) against central differences, and the sampler's elementwise hot path
    (``_pixel_terms``: pixels and ``d(u, v)/dt``) against them; ``dt_tol`` the tolerances
    of that last comparison. Returns the geometry Jacobian."""
    k = lik.hard_wall_index(walls, t)
    R, Jg, Jw, Jt = lik.residuals(g, walls, t, k, sigma, jacobian=True)
    i = np.arange(lik.n)
    num_t = np.stack([numdiff(lambda x, j=j: lik.residuals(g, walls, np.where(i == j, x[0], t),
                                                           k, sigma)[j], [t[j]], 1e-7)[:, 0]
                      for j in range(lik.n)])
    np.testing.assert_allclose(Jt, num_t, rtol=1e-5, atol=1e-6)
    num_g = numdiff(lambda x: lik.residuals(x, walls, t, k, sigma), g,
                    1e-6 * np.maximum(1, np.abs(g)))
    np.testing.assert_allclose(Jg, num_g, rtol=1e-5, atol=1e-5)
    for j in rows:
        def f(x, j=j):
            w = walls.copy()
            w[k[j]] = x
            return lik.residuals(g, w, t, k, sigma)[j]
        np.testing.assert_allclose(Jw[j], numdiff(f, walls[k[j]], [1e-4, 1e-7]),
                                   rtol=1e-5, atol=1e-6)
    d, a = walls[k, 0], walls[k, 1]
    u, v, du, dv = lik._pixel_terms(g[None], t[None], d[None], np.cos(a)[None],
                                    np.sin(a)[None])
    np.testing.assert_allclose(np.stack([u[0], v[0]], -1), R * sigma + lik.pixels, rtol=1e-12)
    np.testing.assert_allclose(np.stack([du[0], dv[0]], -1), Jt * sigma, **dt_tol)
    return Jg


# A camera and board poses like the shared real views (1280x1024, 8 x 6 corners of 42 mm,
# boards 330-420 mm away, 14-42 deg below the horizon), in the package's sign convention
# (gamma_v < 0): rotation vector (rad) and translation (mm), board frame -> frame C.
REAL_LIKE_CAMERA = {"xi": 1.134, "gamma_u": 317.8, "gamma_v": -318.0, "u0": 642.5, "v0": 522.9}
REAL_LIKE_POSES = np.array([
    [-2.0522, 1.1369, -0.44281, 208.0, 336.0, -119.0],
    [2.7646, -1.3874, -0.029836, 219.0, 391.0, -286.0],
    [2.9563, 1.0625, -0.030796, 10.0, -269.0, -247.0],
    [1.6959, 0.47, 0.27156, 35.0, -312.0, -172.0],
    [1.2206, 0.59749, 0.027576, 11.0, -425.0, -195.0],
])


def write_rendered_boards(folder, poses=REAL_LIKE_POSES, *, camera=REAL_LIKE_CAMERA, rng=0):
    """Render one PGM per pose into ``folder``; returns the paths and the true views."""
    import imageio.v3 as iio

    import bayescal as bc

    paths, truths = [], []
    for k, pose in enumerate(poses):
        img, truth = bc.render_board(camera, pose, rng=np.random.default_rng([rng, k]))
        path = folder / f"board_{k}.pgm"
        iio.imwrite(path, img)
        paths.append(path)
        truths.append(truth)
    return paths, truths


def run_cli(*args, cwd, env=None):
    """``bayescal ARGS`` in ``cwd``; returns ``returncode``, ``stdout`` and ``stderr`` like a
    finished subprocess.

    Run in this process (``bayescal.cli.main.main``), with the warning filters a fresh
    interpreter starts with and ``env`` (variables the command reads) set for the call: an
    interpreter and bayescal's imports per command cost 1-2 s of CPU each, most of the
    command-line tests' time. The console entry point's own exit path (Ctrl-C,
    ``os._exit``) is tested by subprocess where it matters."""
    from bayescal.cli.main import main

    out, err, here = io.StringIO(), io.StringIO(), os.getcwd()
    saved = {k: os.environ.get(k) for k in (env or {})}
    os.environ.update(env or {})
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), \
                warnings.catch_warnings():
            warnings.resetwarnings()          # the filters of a fresh interpreter
            warnings.simplefilter("default")
            for cat in (DeprecationWarning, PendingDeprecationWarning, ImportWarning,
                        ResourceWarning):
                warnings.filterwarnings("ignore", category=cat)
            code = main([str(a) for a in args])
    finally:
        os.chdir(here)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return types.SimpleNamespace(returncode=code, stdout=out.getvalue(), stderr=err.getvalue())
