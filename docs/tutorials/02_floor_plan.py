"""
Calibrating from a rough floor plan
===================================

Often the room is known as a plan, not as 3D points: wall positions taken with a tape or
read off a drawing. Each wall's error is then shared by every laser point on it. A
:class:`bayescal.FloorPlan` says so, and the calibration estimates the walls with the sensor.
"""

# %%
import os

import numpy as np

import bayescal as bc

QUICK = os.environ.get("BAYESCAL_DOCS_QUICK") == "1"
ds = bc.simulate_room(range_mm=2500, n_points=200 if QUICK else 580, sigma_px=0.2,
                      approx_error=0.03, approx_model="wall", rng=2)

# %%
# The plan as measured: wall end points (W, 2, 2) in mm, each wall's distance known to
# 3 % and its orientation to 0.01 rad.
walls = ds.floor_plan.walls
plan = bc.FloorPlan(walls, distance_sd=0.03 * ds.floor_plan.distances, angle_sd=0.01)
res = bc.calibrate_simultaneous(ds.pixels, plan, sigma_px=0.2)
print(res.summary())
print("mean 3D error:", np.mean(np.linalg.norm(res.points - ds.points, axis=1)).round(1), "mm")

# %%
# The plan view: the walls as given (dashed) and as estimated, the points with their
# uncertainty ellipses.
from bayescal.plotting import plot_floor_plan  # noqa: E402

fig = plot_floor_plan(plan, walls=res.extras["walls"],
                      wall_covariance=res.extras["wall_covariance"], points=res.points,
                      point_covariance=res.point_covariance(), truth_points=ds.points)
