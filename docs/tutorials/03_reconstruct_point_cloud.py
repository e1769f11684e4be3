"""
Reconstructing new pixels, and a point cloud out
================================================

After calibration, every frame of laser pixels becomes 3D points with a covariance each.
The calibration is prepared once; a frame of 2000 pixels then takes about a millisecond.
"""

# %%
import os
import pathlib
import tempfile
import time

import numpy as np

import bayescal as bc
from bayescal.plotting import plot_reconstruction_ellipses

QUICK = os.environ.get("BAYESCAL_DOCS_QUICK") == "1"
ds = bc.simulate_room(range_mm=2500, n_points=150 if QUICK else 300, n_walls=6,
                      sigma_px=0.2, approx_error=0.03, approx_model="gaussian", rng=0)
post = bc.sample_posterior(ds.pixels, ds.approx_points, sigma_px=0.2,
                           sigma_scene=ds.sigma_scene, rng=1, progress=False,
                           min_ess=300 if QUICK else 1000)

# %%
# A new frame: 2000 laser pixels of the same room seen again.
frame = bc.simulate_room(range_mm=2500, n_points=2000, n_walls=6, sigma_px=0.2, rng=5)
rc = post.reconstructor()              # one-time preparation, checked against sampling
print(rc.agreement)
t0 = time.perf_counter()
rec = post.reconstruct(frame.pixels)
print(f"2000 pixels in {1e3 * (time.perf_counter() - t0):.1f} ms")
mean, cov = rec

# %%
# How honest are the error bars? The fraction of true points inside their 90 % ellipsoid.
from scipy import stats  # noqa: E402

d = frame.points - mean
nse = np.einsum("mi,mij,mj->m", d, np.linalg.inv(cov), d)
print("inside the 90 % ellipsoids:", np.mean(nse < stats.chi2.ppf(0.9, 3)).round(3))

# %%
# The points seen from above with their 95 % ellipses.
fig = plot_reconstruction_ellipses(mean, cov)

# %%
# A binary PLY with the six covariance entries per point, for Open3D, MeshLab or ROS.
path = rec.save(pathlib.Path(tempfile.mkdtemp()) / "frame.ply")
print(path.name, path.stat().st_size, "bytes")
