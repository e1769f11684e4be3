"""
From a CSV of laser pixels to a posterior
=========================================

A file with one laser point per row: its pixel ``(u, v)`` and its approximate 3D position
``(x, y, z)`` in mm, measured roughly. We calibrate it by least squares (the paper's
simultaneous method), then sample the posterior over the eight sensor parameters and every
point, and look at a corner plot.
"""

# %%
# A CSV as a user would have it. Here we write one from a simulated 1000 mm room (580 laser
# points, 0.2 px pixel noise, approximate points 3 % off), then read it back.
import os
import pathlib
import tempfile

import numpy as np

import bayescal as bc

QUICK = os.environ.get("BAYESCAL_DOCS_QUICK") == "1"
ds = bc.simulate_room(range_mm=1000, n_points=150 if QUICK else 580, sigma_px=0.2,
                      approx_error=0.03, approx_model="gaussian", rng=0)
folder = pathlib.Path(tempfile.mkdtemp())
np.savetxt(folder / "laser.csv", np.column_stack([ds.pixels, ds.approx_points]),
           delimiter=",", header="u,v,x,y,z", comments="")

data = np.genfromtxt(folder / "laser.csv", delimiter=",", names=True)
pixels = np.column_stack([data["u"], data["v"]])
approx = np.column_stack([data["x"], data["y"], data["z"]])
print(pixels.shape, approx.shape)

# %%
# Least squares. ``sigma_scene=None`` infers how far off the approximate points are (a
# relative error ``kappa * range``); ``sigma_px`` is the pixel noise, also inferable.
res = bc.calibrate_simultaneous(pixels, approx, sigma_px=0.2, sigma_scene=None)
print(res.summary())

# %%
# Does the model fit its data? The predictive check compares the standardized residuals
# with what the model predicts.
print(res.model_check().message)

# %%
# The posterior: emcee over the identifiable parameters with each point integrated out,
# then the points drawn. Its summary flags phi and alpha as prior-dominated (only
# ``alpha (xi + phi)`` is seen by the data).
post = bc.sample_posterior(pixels, approx, sigma_px=0.2, sigma_scene=None, rng=1,
                           min_ess=300 if QUICK else 1000, progress=False)
print(post.summary())

# %%
# The corner plot of the seven identifiable parameters, with the truth of the simulation.
fig = post.corner(identifiable=True, truth=ds.params)
