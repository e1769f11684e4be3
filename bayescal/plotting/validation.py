"""Figures of the validation experiments (:mod:`bayescal.validation.coverage`).

Coverage, normalised squared errors, SBC ranks.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from ..validation.coverage import LEVELS, SBC_BINS, SBC_DRAWS, THETA_NAMES, binomial_band

__all__ = ["plot_coverage", "plot_nse", "plot_sbc"]


def plot_coverage(summ, path):
    import matplotlib.pyplot as plt

    lev = np.array(LEVELS)
    fig, axes = plt.subplots(2, 2, figsize=(10, 8.5), sharex=True, sharey=True)
    for row, room in enumerate(summ):
        s = summ[room]
        m = s["m"]
        lo = [binomial_band(m, v)[0] for v in lev]
        hi = [binomial_band(m, v)[1] for v in lev]
        for col, key in enumerate(("", "_map")):
            ax = axes[row, col]
            ax.fill_between(lev, lo, hi, color="0.85", label="99 % binomial band")
            ax.plot(lev, lev, "k--", lw=1)
            for k, name in enumerate(THETA_NAMES):
                ln, = ax.plot(lev, s["theta" + key][:, k], "o-", ms=3, lw=1, label=name)
                if s["z_sd_expected"][k] < 0.9:  # visibly above nominal: show the expectation
                    ax.plot(lev, s["theta_expected"][:, k], ":", color=ln.get_color(), lw=1)
            ax.errorbar(lev, s["points" + key], yerr=2 * s["points_se" + key], fmt="ks-",
                        lw=2, ms=5, label="points (pooled, +-2 se)")
            ax.set_title(f"{room} room, {'MCMC' if not key else 'MAP/Laplace'} (M={m})")
            ax.set_xlabel("nominal level")
            ax.set_ylabel("empirical coverage")
    axes[0, 0].legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_nse(summ, path):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(summ), figsize=(10, 4))
    x = np.linspace(0, 16, 200)
    for ax, room in zip(np.atleast_1d(axes), summ, strict=True):
        for key, c in (("", "C0"), ("_map", "C1")):
            v = summ[room]["nse_pooled" + key]
            ax.hist(np.clip(v, 0, 16), bins=40, range=(0, 16), density=True, histtype="step",
                    color=c, lw=1.5, label=("MCMC" if not key else "MAP/Laplace")
                    + f" (mean {np.mean(v):.2f})")
        ax.plot(x, stats.chi2(3).pdf(x), "k--", label="chi-square(3)")
        ax.set_title(f"{room} room: point normalised squared errors")
        ax.set_xlabel("(mean - truth)^T Cov^-1 (mean - truth)")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_sbc(counts, chi2, n_sims, path):
    import matplotlib.pyplot as plt

    names = list(THETA_NAMES) + ["phi"]
    fig, axes = plt.subplots(2, 4, figsize=(12, 5.5), sharey=True)
    e = n_sims / SBC_BINS
    lo, hi = stats.binom(n_sims, 1 / SBC_BINS).ppf([0.005, 0.995])
    for ax, name, c, x2 in zip(axes.ravel(), names, counts, chi2, strict=True):
        ax.axhspan(lo, hi, color="0.85")
        ax.axhline(e, color="k", lw=1, ls="--")
        ax.bar(np.arange(SBC_BINS), c, width=0.9, color="C0")
        ax.set_title(f"{name}: chi2(9) = {x2:.1f}", fontsize=10)
        ax.set_xlabel("rank bin")
    fig.suptitle(f"SBC rank histograms ({n_sims} simulations, {SBC_DRAWS} draws, grey: 99 % "
                 "band per bin)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
