"""Extraction errors shared along a wall, and what they do to a floor-plan calibration.

For images from three renderers (ours, ``bc.render_image``; ``tests/image/renderer2.py``;
and optionally a third one given by ``--renderer3 PATH/renderer3.py``), with and without the
laser-off frame: extract the ring (``bc.extract_laser(..., along_sd=1)``, as
``bayescal extract --along-sd 1``), measure each unflagged point's error along the true
ring's normal, and report

- per wall: the mean error and its z against the sd the extractor's covariances predict for
  a mean of independent errors (``sqrt(sum sd_i^2) / n``);
- the errors' correlation against the azimuth lag, for pairs on the same wall and on
  neighbouring walls (constant per wall, or smooth over tens of degrees?);
- the floor-plan calibration (``calibrate_simultaneous(pixels, plan, sigma_px=None,
  pixel_cov=...)``, a plan drawn 2 % off the true walls) against the truth in its sds, with
  the Laplace covariance, with a residual sandwich (HAC) and with ``ring_corr_deg``;
  and the MAP's shift that the measured errors predict to first order (all of them, and
  their per-wall means only).

Usage::

    python studies/wallbias.py --out out/wallbias [--renderer3 PATH/renderer3.py]
        [--seeds 3] [--hac 3 12] [--ring 1 2] [--wall 0.1]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import pathlib
import sys

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests" / "image"))       # renderer2.py

import bayescal as bc  # noqa: E402

IDENT = ("xi", "gamma_u", "gamma_v", "u0", "v0", "h", "beta")
LAGS = (0.0, 2.0, 5.0, 10.0, 20.0, 40.0, 90.0)                 # deg, bin edges
#: renderer: scenarios (name, laser-off frame used)
CASES = {
    "ours": [("textured", False), ("textured", True)],
    "renderer2": [("textured_2500", False), ("textured_2500", True), ("red_bayer", False)],
    "renderer3": [("textured", False), ("red", False), ("faint", True), ("faint", False)],
}


def _load_r3(path):
    spec = importlib.util.spec_from_file_location("renderer3", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["renderer3"] = mod
    spec.loader.exec_module(mod)
    return mod


def render(renderer, scenario, seed, r3=None):
    """(image, laser-off, true params, true ring pixels (M, 2), azimuths (M,), usable (M,),
    true walls (W, 2, 2))."""
    if renderer == "ours":
        p = bc.SensorParams.paper()
        walls = bc.room_walls(2500.0)
        img, tr = bc.render_image(p, walls, with_background=True, n_lamps=0, rng=seed)
        return img, tr.background, p, tr.pixels, tr.azimuth, np.ones(len(tr.azimuth), bool), walls
    if renderer == "renderer2":
        from renderer2 import render_scenario

        img, off, tr = render_scenario(scenario, rng=seed)
        return img, off, tr.params, tr.pixels, tr.azimuth, tr.visible & ~tr.near_lamp, tr.walls
    img, off, tr = r3.render3(scenario, seed)
    c = tr.room.corners
    walls = np.stack([c, np.roll(c, -1, axis=0)], axis=1)
    use = tr.visible & ~(tr.hidden if tr.hidden is not None else False)
    if tr.room.cabinet is not None:
        raise ValueError("a room with furniture is not a floor plan's room")
    return img, off, tr.params, tr.pixels, tr.azimuth, use, walls


def wall_of(az, walls):
    """Index of the wall (W, 2, 2), counterclockwise, seen at azimuths ``az`` (N,)."""
    a0 = np.arctan2(walls[:, 0, 1], walls[:, 0, 0])
    span = np.mod(np.arctan2(walls[:, 1, 1], walls[:, 1, 0]) - a0, 2 * np.pi)
    rel = np.mod(az[:, None] - a0[None], 2 * np.pi)
    return np.argmax(rel < span[None], axis=1)


def normal_errors(lp, tpix, taz, use):
    """Per unflagged point: error along the true ring's normal (px), its given sd, the true
    azimuth (rad) and whether it is on the usable ring (not gross, > 1 px)."""
    from scipy.spatial import cKDTree

    ok = ~lp.flagged
    tan = np.roll(tpix, -1, 0) - np.roll(tpix, 1, 0)
    tan /= np.linalg.norm(tan, axis=1)[:, None]
    nrm = np.stack([tan[:, 1], -tan[:, 0]], -1)
    fin = np.all(np.isfinite(tpix), axis=1)
    idx = np.flatnonzero(fin)
    _, j = cKDTree(tpix[idx]).query(lp.pixels)
    k = idx[j]
    e = np.sum((lp.pixels - tpix[k]) * nrm[k], axis=1)
    c = lp.center
    e *= np.sign(np.sum(nrm[k] * (tpix[k] - c), axis=1))        # + outwards
    good = ok & use[k] & (np.abs(e) <= 1.0)
    return e, lp.sd_normal, taz[k], good, nrm[k]


def wall_stats(e, sd, wall, good):
    """Per wall: n, mean error, predicted sd of the mean, z."""
    rows = []
    for w in np.unique(wall[good]):
        m = good & (wall == w)
        n = int(m.sum())
        pred = float(np.sqrt(np.sum(sd[m] ** 2)) / n)
        rows.append(dict(wall=int(w), n=n, mean=float(e[m].mean()), pred_sd=pred,
                         z=float(e[m].mean() / pred)))
    return rows


def lag_correlation(e, az, wall, good):
    """Correlation of the errors (global mean removed) per azimuth-lag bin, same wall and
    different walls."""
    x = e[good] - e[good].mean()
    a, w = az[good], wall[good]
    lag = np.degrees(np.abs(np.angle(np.exp(1j * (a[:, None] - a[None])))))
    same = w[:, None] == w[None]
    prod = x[:, None] * x[None] / np.mean(x * x)
    out = {}
    for lo, hi in zip(LAGS[:-1], LAGS[1:], strict=True):
        b = (lag > lo) & (lag <= hi)
        for name, sel in (("same", b & same), ("other", b & ~same)):
            out[f"{name}_{lo:g}_{hi:g}"] = float(prod[sel].mean()) if sel.sum() > 20 else None
    return out


def lag_products(e, az, good, max_deg=60):
    """Sums of products of the errors (global mean removed, px^2) and pair counts per
    1-degree lag bin (bin k: lags in [k - 0.5, k + 0.5) deg; bin 0 the points themselves)."""
    x = e[good] - e[good].mean()
    a = az[good]
    lag = np.degrees(np.abs(np.angle(np.exp(1j * (a[:, None] - a[None])))))
    k = np.rint(lag).astype(int)
    m = k <= max_deg
    prod = np.bincount(k[m], (x[:, None] * x[None])[m], max_deg + 1)
    return prod.tolist(), np.bincount(k[m], minlength=max_deg + 1).tolist()


def rough_plan(walls, rng, rel_sd=0.02, angle_sd=0.005):
    """A plan a user would measure: each wall line off by a draw (distance sd 5 %)."""
    a = walls[:, 1] - walls[:, 0]
    nrm = np.stack([a[:, 1], -a[:, 0]], -1) / np.linalg.norm(a, axis=1)[:, None]
    d = np.sum(nrm * walls[:, 0], axis=1)
    ang = np.arctan2(nrm[:, 1], nrm[:, 0]) + angle_sd * rng.standard_normal(len(d))
    d = d * (1 + rel_sd * rng.standard_normal(len(d)))
    return bc.FloorPlan.from_lines(d, ang, distance_sd=0.05 * d, angle_sd=0.01)


def identifiable(p):
    s = p.xi + p.phi
    return np.array([p.xi, p.alpha_u * s, p.alpha_v * s, p.u0, p.v0, p.h, p.beta])


def kernel(t, sd, scale_deg):
    """Covariance (N, N) px^2 of a normal error with sd ``sd`` correlated over azimuth
    (``t`` rad) as ``exp(-lag^2 / (2 scale^2))``."""
    lag = np.angle(np.exp(1j * (t[:, None] - t[None])))
    return sd ** 2 * np.exp(-0.5 * (lag / np.radians(scale_deg)) ** 2)


def hac_cov(lik, sol, bandwidth_deg):
    """A residual-based sandwich (Bartlett weights over azimuth, HAC) of ``g``: ``S^-1
    (Lambda + sum_ij k_ij h_i e_i e_j h_j^T) S^-1``, ``Lambda`` the prior rows' information."""
    from bayescal.fit.floorplan import normal_sensitivity

    P, sd = normal_sensitivity(lik, sol)
    h = -np.linalg.solve(sol.cov, P).T                    # the gradient's change per px
    o, W = lik.n_geo + 1, lik.n_walls
    R = lik.residuals(sol.g[:o - 1], sol.g[o:].reshape(W, 2), sol.t, sol.wall_index, 1.0)
    if lik.px_white is not None:                # unwhitened: model - pixel, px
        a, b, c = lik.px_white.T
        R = np.stack([(R[:, 0] - b * R[:, 1] / c) / a, R[:, 1] / c], axis=1)
    rad = lik.pixels - sol.g[3:5]
    e = -np.sum(R * rad / np.linalg.norm(rad, axis=1, keepdims=True), axis=1)
    lag = np.abs(np.angle(np.exp(1j * (sol.t[:, None] - sol.t[None]))))
    K = np.clip(1.0 - lag / np.radians(bandwidth_deg), 0.0, None)
    he = h * e[:, None]
    info = he.T @ K @ he
    info[:o, :o] += sol.ne["Jp"].T @ sol.ne["Jp"]
    info[o:, o:] += np.diag(1.0 / lik.plan.param_sd ** 2)
    return sol.cov @ info @ sol.cov


def calibrate_z(pix, cov, plan, truth, offset_sd, errors, variants):
    """The floor-plan MAP's identifiable parameters against the truth in their sds, with the
    Laplace covariance (``plain``) and each variant: ``("hac", bandwidth deg)`` (a sandwich
    on the fit's residuals) or ``("ring", scale deg)`` (``ring_corr_cov``); and the
    first-order shift of the MAP that the measured errors predict (``shift_pred_sd``), and
    its part from the per-wall means of the errors (``shift_wallmean_sd``)."""
    from bayescal.fit.floorplan import _fit, normal_sensitivity, ring_corr_cov

    try:
        lik, _, sol = _fit(pix, plan, sigma_px=None, prior=None, init=None, max_iter=200,
                           pixel_cov=cov)
    except (ValueError, bc.ConvergenceError) as exc:
        return {"error": str(exc)[:200]}
    P = normal_sensitivity(lik, sol)[0][:7]
    err = (sol.g[:7] - identifiable(truth))
    off = np.diag([0, 0, 0, offset_sd ** 2, offset_sd ** 2, 0, 0])
    out = {"check_ok": bool(sol.check["ok"]), "sigma_scale": sol.sigma_px}
    W = lik.n_walls
    for name, v in {"plain": None, **variants}.items():
        if v is None:
            c = sol.cov
        elif v[0] == "hac":
            c = hac_cov(lik, sol, v[1])
        elif v[0] == "wall":            # a pixel offset of sd v[1] shared by each wall's points
            full = normal_sensitivity(lik, sol)[0]
            V = np.zeros((W, len(full)))
            np.add.at(V, sol.wall_index, full.T)
            c = sol.cov + v[1] ** 2 * V.T @ V
        else:
            c = sol.cov + ring_corr_cov(lik, sol, v[1])
        out[name] = dict(zip(IDENT, np.round(err / np.sqrt(np.diag(c[:7, :7] + off)),
                                             3).tolist(), strict=True))
    sd7 = np.sqrt(np.diag(sol.cov[:7, :7] + off))
    e = np.where(np.isfinite(errors), np.clip(errors, -1.0, 1.0), 0.0)
    wm = np.zeros(W)
    np.add.at(wm, sol.wall_index, e)
    wm /= np.maximum(np.bincount(sol.wall_index, minlength=W), 1)
    out["shift_pred_sd"] = dict(zip(IDENT, np.round(P @ e / sd7, 3).tolist(), strict=True))
    out["shift_wallmean_sd"] = dict(zip(IDENT, np.round(P @ wm[sol.wall_index] / sd7,
                                                        3).tolist(), strict=True))
    return out


def trial(renderer, scenario, background, seed, r3, variants):
    img, off, p, tpix, taz, use, walls = render(renderer, scenario, seed, r3)
    try:
        lp = bc.extract_laser(img, background=off if background else None, along_sd=1.0)
    except bc.ExtractionError as exc:
        return dict(renderer=renderer, scenario=scenario, background=background, seed=seed,
                    error=exc.reason)
    e, sd, az, good, _ = normal_errors(lp, tpix, taz, use)
    ok = ~lp.flagged
    wall = wall_of(az, walls)
    out = dict(renderer=renderer, scenario=scenario, background=background, seed=seed,
               walls=wall_stats(e, sd, wall, good), lags=lag_correlation(e, az, wall, good),
               lag_products=lag_products(e, az, good),
               point_sd=float(np.sqrt(np.mean(sd[good] ** 2))),
               robust_sd=float(1.4826 * np.median(np.abs(e[good] - np.median(e[good])))))
    plan = rough_plan(walls, np.random.default_rng(1000 + seed))
    out["calib"] = calibrate_z(lp.pixels[ok], lp.covariance[ok], plan, p, lp.offset_sd,
                               e[ok], variants)
    return out


def fit_kernel(prod, count, max_lag=40, scales=(1, 2, 3, 5, 8, 12, 20, 30)):
    """Pooled error covariance per 1-degree lag (px^2) and the exponential kernel
    ``s^2 exp(-lag / scale)`` fitted (count-weighted least squares) to lags 1..max_lag:
    ``(cov per lag, s, scale)``."""
    prod, count = np.sum(prod, axis=0), np.sum(count, axis=0)
    c = prod / np.maximum(count, 1)
    k = np.arange(1, max_lag + 1)
    w, y = count[k], c[k]
    best = None
    for sc in scales:
        f = np.exp(-k / sc)
        s2 = max(float(np.sum(w * y * f) / np.sum(w * f * f)), 0.0)
        sse = float(np.sum(w * (y - s2 * f) ** 2))
        best = (sse, np.sqrt(s2), sc) if best is None or sse < best[0] else best
    return c, best[1], best[2]


def summarize(rows):
    """Per renderer and laser-off setting: pooled lag covariance, fitted kernel, and the
    rms over images of the z of u0, v0 and of all seven, per covariance variant."""
    groups = {}
    for r in rows:
        if "calib" in r and "error" not in r["calib"]:
            groups.setdefault((r["renderer"], r["scenario"], r["background"]), []).append(r)
    for (ren, sc, bg), rs in groups.items():
        c, s, scale = fit_kernel([r["lag_products"][0] for r in rs],
                                 [r["lag_products"][1] for r in rs])
        print(f"{ren} {sc} bg={int(bg)} n={len(rs)}: var {c[0]:.4f} px^2, corr at 1,2,3,5,"
              f"10,20 deg {np.round(c[[1, 2, 3, 5, 10, 20]] / c[0], 3).tolist()}; "
              f"kernel s {s:.3f} px, scale {scale} deg")
        names = [k for k in rs[0]["calib"] if k.startswith(("plain", "hac", "ring", "wall"))]
        for n in names:
            z = np.array([[r["calib"][n][p] for p in IDENT] for r in rs])
            print(f"    {n:14s} z rms u0 {np.sqrt(np.mean(z[:, 3] ** 2)):.2f} v0 "
                  f"{np.sqrt(np.mean(z[:, 4] ** 2)):.2f} all {np.sqrt(np.mean(z ** 2)):.2f} "
                  f"max|z| {np.max(np.abs(z)):.2f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--summarize", action="store_true", help="summarise --out's JSON")
    ap.add_argument("--renderer3", default=None)
    ap.add_argument("--renderers", default="ours,renderer2,renderer3")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--hac", type=float, nargs="*", default=[3.0, 12.0],
                    help="bandwidths (deg) of the residual sandwich")
    ap.add_argument("--ring", type=float, nargs="*", default=[1.0, 2.0],
                    help="correlation scales (deg) of ring_corr_cov")
    ap.add_argument("--wall", type=float, nargs="*", default=[0.1],
                    help="sds (px) of a pixel offset shared by each wall's points")
    a = ap.parse_args(argv)
    r3 = _load_r3(a.renderer3) if a.renderer3 else None
    variants = {f"hac {b:g}": ("hac", b) for b in a.hac}
    variants |= {f"ring {sc:g}": ("ring", sc) for sc in a.ring}
    variants |= {f"wall {sd:g}": ("wall", sd) for sd in a.wall}
    out = pathlib.Path(a.out)
    if a.summarize:
        return summarize(json.loads((out / "wallbias.json").read_text()))
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for r in a.renderers.split(","):
        if r == "renderer3" and r3 is None:
            continue
        for sc, bg in CASES[r]:
            for seed in range(a.seeds):
                t = trial(r, sc, bg, seed, r3, variants)
                rows.append(t)
                (out / "wallbias.json").write_text(json.dumps(rows, indent=1))
                print(summary_line(t), flush=True)


def summary_line(t):
    head = f"{t['renderer']:9s} {t['scenario']:13s} bg={int(t['background'])} seed={t['seed']}"
    if "error" in t:
        return head + " extraction error: " + t["error"]
    wz = [w["z"] for w in t["walls"] if w["n"] >= 5]
    wm = [w["mean"] for w in t["walls"] if w["n"] >= 5]
    c = t["calib"]
    if "error" in c:
        cal = "calibration failed"
    else:
        cal = f"u0/v0 z {c['plain']['u0']:+.2f} {c['plain']['v0']:+.2f} (pred " \
              f"{c['shift_pred_sd']['u0']:+.2f} {c['shift_pred_sd']['v0']:+.2f}, wall means " \
              f"{c['shift_wallmean_sd']['u0']:+.2f} {c['shift_wallmean_sd']['v0']:+.2f})" + \
              "".join(f" | {k}: {v['u0']:+.2f} {v['v0']:+.2f} max "
                      f"{max(abs(x) for x in v.values()):.2f}"
                      for k, v in c.items() if k.startswith(("plain", "hac", "ring", "wall")))
    return (f"{head} pt_sd {t['point_sd']:.3f} rob {t['robust_sd']:.3f} | wall z rms "
            f"{np.sqrt(np.mean(np.square(wz))):.2f} max|mean| {max(np.abs(wm)):.3f} | {cal}")


if __name__ == "__main__":
    main()
