"""An independent reference posterior: NUTS (NumPyro) on the full joint, for validation.

bayescal's sampler integrates every laser point out (a per-point Laplace step)
and runs emcee over the identifiable parameters. To check it against something
it does not share code with, this module writes the *full joint* posterior
over the eight paper parameters and all ``2N`` scene coordinates in JAX, from
the paper's equations, and samples it with NumPyro's NUTS. Nothing here calls
bayescal's camera, laser, likelihood or prior code: only the data arrays and
the prior's scipy distributions (normal priors) are read.

The target is the one bayescal samples (``docs/bayes.md``):

* priors: independent normals on ``(xi, phi, alpha_u, alpha_v, u0, v0, h, beta)``;
* point ``i`` at scene coordinates ``q_i = (x_i, y_i)`` lies on the cone,
  ``P_i = (x_i, y_i, rho_i / tan(beta) - h)``;
* ``pixels_i ~ N(project(P_i), sigma_px^2 I)``, eq. (1) of the paper;
* ``approx_i ~ N(P_i, diag(sigma_scene_i^2))`` on the axes where
  ``sigma_scene`` is finite;
* each point's prior is Jeffreys', ``|J_i^T J_i|^(1/2)`` with ``J_i`` the
  Jacobian of point ``i``'s whitened residuals with respect to ``q_i``.

When the approximate points carry no ``z`` the points' conditional posteriors
are long and thin, and NUTS on the plain coordinates diverges. Each point is
therefore written non-centred around its conditional mode:
``q_i = m_i(a) + L_i(a) z_i`` with ``m_i`` a few unrolled Gauss-Newton steps
and ``L_i L_i^T = (J_i^T J_i)^-1`` at ``m_i``; the change of variables adds
``log |L_i|`` to the density, so the target is unchanged whatever ``m_i`` is.

The misaligned model (``model="misaligned"``): four more unknowns, the laser cone's
``(tilt_x, tilt_y, offset_x, offset_y)`` with normal priors, and the point's height from
the cone written here in frame C, independently of bayescal's formulation in the cone's
own frame: with apex ``A = (offset_x, offset_y, -h)``, unit axis ``a`` (the convention
of ``docs/conventions.md``: ``a = (cos tx sin ty, -sin tx, cos tx cos ty)``) and
``d = P - A``, the point satisfies ``(d . a)^2 = cos^2(beta) |d|^2`` with ``d . a > 0``;
along the vertical line through ``(x, y)`` that is a quadratic in ``z`` whose larger
root is the lit nappe.

Requires the optional ``nuts`` extra (``pip install bayescal[nuts]``: jax and
numpyro); nothing is imported until :func:`sample_nuts` is called.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidValueError

__all__ = ["sample_nuts", "nuts_available"]

_ORDER = ("xi", "phi", "alpha_u", "alpha_v", "u0", "v0", "h", "beta")
_POSE = ("tilt_x", "tilt_y", "offset_x", "offset_y")


def nuts_available():
    """True when jax and numpyro can be imported."""
    try:
        import jax  # noqa: F401
        import numpyro  # noqa: F401
    except ImportError:
        return False
    return True


def _normal_prior(prior, misaligned=False):
    """(loc, scale) arrays of the eight normal priors, in paper order (then the pose's)."""
    dists = dict(getattr(prior, "dists", prior))
    dists.update(getattr(prior, "pose_dists", {}))
    loc, scale = [], []
    for name in _ORDER + (_POSE if misaligned else ()):
        d = dists[name]
        if getattr(getattr(d, "dist", None), "name", None) != "norm":
            raise InvalidValueError(
                f"the NUTS reference supports normal priors only; prior[{name!r}] "
                f"is {getattr(d.dist, 'name', type(d).__name__)}")
        loc.append(float(d.mean()))
        scale.append(float(d.std()))
    return np.array(loc), np.array(scale)


def _model_functions(pixels, approx, w_scene, sigma_px):
    """JAX functions of the joint model (closures over the data)."""
    import jax
    import jax.numpy as jnp

    pix = jnp.asarray(pixels)
    apx = jnp.asarray(approx)
    w = jnp.asarray(w_scene)
    inv_s = 1.0 / sigma_px

    def point_residual(a, q, pix_i, apx_i, w_i):
        xi, phi, au, av, u0, v0, h, beta = (a[k] for k in range(8))
        x, y = q[0], q[1]
        z = _height(a, x, y)
        r = jnp.sqrt(x * x + y * y + z * z)
        den = xi * r - z
        s = xi + phi
        return jnp.stack([(au * s * x / den + u0 - pix_i[0]) * inv_s,
                          (av * s * y / den + v0 - pix_i[1]) * inv_s,
                          (x - apx_i[0]) * w_i[0],
                          (y - apx_i[1]) * w_i[1],
                          (z - apx_i[2]) * w_i[2]])

    def _height(a, x, y):
        h, beta = a[6], a[7]
        if a.shape[0] == 8:
            return jnp.sqrt(x * x + y * y) / jnp.tan(beta) - h
        tx, ty, ox, oy = a[8], a[9], a[10], a[11]
        ax = jnp.stack([jnp.cos(tx) * jnp.sin(ty), -jnp.sin(tx), jnp.cos(tx) * jnp.cos(ty)])
        d0 = jnp.stack([x - ox, y - oy, h])             # P - A at z = 0
        c2 = jnp.cos(beta) ** 2
        da = d0 @ ax
        qa = ax[2] ** 2 - c2                            # (da + z a_z)^2 - c2 |d0 + z e_z|^2
        qb = da * ax[2] - c2 * d0[2]
        qc = da * da - c2 * (d0 @ d0)
        return (-qb + jnp.sqrt(qb * qb - qa * qc)) / qa

    jac_q = jax.jacfwd(point_residual, argnums=1)
    res_all = jax.vmap(point_residual, in_axes=(None, 0, 0, 0, 0))
    jac_all = jax.vmap(jac_q, in_axes=(None, 0, 0, 0, 0))

    def info(a, q):
        """Per-point residuals (N, 5), Jacobians (N, 5, 2) and information (N, 2, 2)."""
        R = res_all(a, q, pix, apx, w)
        J = jac_all(a, q, pix, apx, w)
        return R, J, jnp.einsum("nki,nkj->nij", J, J)

    def mode(a, q0, n_iter):
        """Unrolled Gauss-Newton steps towards each point's conditional mode."""
        q = q0
        for _ in range(n_iter):
            R, J, C = info(a, q)
            g = jnp.einsum("nki,nk->ni", J, R)
            q = q - jnp.linalg.solve(C, g[..., None])[..., 0]
        return q

    return info, mode, jax.vmap(_height, in_axes=(None, 0, 0))


def sample_nuts(pixels, approx_points, *, sigma_px, sigma_scene, prior, q_init,
                num_warmup=1000, num_samples=2000, num_chains=2, target_accept=0.95,
                n_gauss_newton=3, rng=0, progress=False, model="aligned"):
    """Sample the full joint posterior with NumPyro NUTS (validation reference).

    Parameters
    ----------
    pixels : array_like, shape (N, 2)
        Laser pixels, px.
    approx_points : array_like, shape (N, 3)
        Approximate 3D points, mm.
    sigma_px : float
        Pixel noise, px (given, not inferred).
    sigma_scene : float or array_like broadcastable to (N, 3)
        Scene noise, mm; ``inf`` where an axis carries no information.
    prior : dict or bayescal.Prior
        Normal priors on the eight parameters (``{name: scipy.stats.norm(...)}``), and
        on the pose's four with ``model="misaligned"`` (a Prior's ``pose_dists``).
    q_init : array_like, shape (N, 2)
        Start of the Gauss-Newton steps that centre each point (e.g. the
        approximate points' (x, y), or a least-squares estimate); it moves the
        parameterization, not the target.
    num_warmup, num_samples, num_chains : int
        NUTS settings (chains run one after the other on the CPU).
    target_accept : float
        NUTS target acceptance probability.
    n_gauss_newton : int
        Unrolled Gauss-Newton steps of the centring.
    rng : int
        Seed of JAX's PRNG.
    progress : bool
        NumPyro's progress bar.
    model : {"aligned", "misaligned"}
        The laser cone: the paper's, or tilted and offset (four more unknowns).

    Returns
    -------
    dict
        ``params`` (S, 8) in paper order, ``laser`` (S, 4) with the misaligned model
        (tilt_x, tilt_y rad, offset_x, offset_y mm), ``points`` (S, N, 3) mm,
        ``divergences`` (int), ``ess`` (8,) and ``r_hat`` (8,) of the
        parameters from NumPyro's diagnostics, ``seconds`` (float).
    """
    import time

    import jax
    import jax.numpy as jnp
    import numpyro
    import numpyro.distributions as dist
    from numpyro.infer import MCMC, NUTS, init_to_value

    jax.config.update("jax_enable_x64", True)
    pixels = np.asarray(pixels, float)
    approx = np.asarray(approx_points, float)
    n = len(pixels)
    s = np.broadcast_to(np.asarray(sigma_scene, float), (n, 3))
    w_scene = np.where(np.isfinite(s), 1.0 / s, 0.0)
    approx = np.where(np.isfinite(approx), approx, 0.0)
    loc, scale = _normal_prior(prior, misaligned=model == "misaligned")
    k = len(loc)
    info, mode, height = _model_functions(pixels, approx, w_scene, float(sigma_px))
    q0 = jnp.asarray(np.asarray(q_init, float))

    def joint():
        eps = numpyro.sample("eps", dist.Normal(jnp.zeros(k), 1.0).to_event(1))
        a = jnp.asarray(loc) + jnp.asarray(scale) * eps
        numpyro.deterministic("a", a)
        m = mode(a, q0, n_gauss_newton)
        _, _, C = info(a, m)
        L = jnp.linalg.cholesky(jnp.linalg.inv(C))                  # (N, 2, 2)
        z = numpyro.sample("z", dist.ImproperUniform(dist.constraints.real_vector, (),
                                                     event_shape=(n, 2)))
        q = m + jnp.einsum("nij,nj->ni", L, z)
        numpyro.deterministic("q", q)
        R, _, Cq = info(a, q)
        log_lik = -0.5 * jnp.sum(R * R)
        log_jeffreys = 0.5 * jnp.sum(jnp.linalg.slogdet(Cq)[1])
        log_jac = jnp.sum(jnp.log(jnp.abs(L[:, 0, 0] * L[:, 1, 1])))
        numpyro.factor("joint", log_lik + log_jeffreys + log_jac)

    init = init_to_value(values={"eps": jnp.zeros(k), "z": jnp.zeros((n, 2))})
    kernel = NUTS(joint, target_accept_prob=target_accept, dense_mass=[("eps",)],
                  init_strategy=init)
    mcmc = MCMC(kernel, num_warmup=int(num_warmup), num_samples=int(num_samples),
                num_chains=int(num_chains), chain_method="sequential",
                progress_bar=progress)
    t0 = time.perf_counter()
    mcmc.run(jax.random.PRNGKey(int(rng)), extra_fields=("diverging",))
    return _collect(mcmc, height, n, k, time.perf_counter() - t0)


def _collect(mcmc, height, n, k, seconds):
    """The returned dict of :func:`sample_nuts` from a finished NumPyro run."""
    import jax
    import jax.numpy as jnp
    from numpyro.diagnostics import effective_sample_size, split_gelman_rubin

    grouped = mcmc.get_samples(group_by_chain=True)
    a = np.asarray(grouped["a"])                                        # (chains, S, k)
    q = np.asarray(grouped["q"]).reshape(-1, n, 2)
    a_flat = a.reshape(-1, k)
    z = np.asarray(jax.vmap(height, in_axes=(0, 0, 0))(jnp.asarray(a_flat), q[..., 0],
                                                       q[..., 1]))
    extra = mcmc.get_extra_fields(group_by_chain=False)
    out = {"params": a_flat[:, :8], "points": np.concatenate([q, z[..., None]], axis=-1),
           "divergences": int(np.sum(np.asarray(extra["diverging"]))),
           "ess": np.asarray(effective_sample_size(a)),
           "r_hat": np.asarray(split_gelman_rubin(a)), "seconds": seconds}
    if k > 8:
        out["laser"] = a_flat[:, 8:]
    return out
