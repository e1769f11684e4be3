"""
Calibrating the camera from chessboard views
============================================

Before the laser, the camera: its five intrinsics of eq. (1) (``xi``, ``gamma_u``,
``gamma_v``, ``u0``, ``v0``) from a chessboard held in several poses around the mirror.
OpenCV finds the corners (``pip install bayescal[camera]``); bayescal fits one pose per
view and the intrinsics, with a noise model for the corners and a covariance that
cross-validation can check.

Here the images are rendered by the package, through a camera like the real one of
``../shared/data/para`` (1280 x 1024 px, a board of 8 x 6 inner corners on 42 mm squares),
so the truth is known. With real images, replace the rendered arrays by file names::

    import glob
    views = [bc.find_chessboard(p, board=(8, 6), square=42.0)
             for p in sorted(glob.glob("views/*.pgm"))]

or, from the shell, ``bayescal calibrate-camera views/*.pgm --board 8x6 --square 42 --out
cam`` (:doc:`../cli`).
"""

# %%
import os

import matplotlib.pyplot as plt
import numpy as np

import bayescal as bc

QUICK = os.environ.get("BAYESCAL_DOCS_QUICK") == "1"
N_VIEWS = 4 if QUICK else 6

# %%
# The true camera, and board poses where a person would hold the board: 350-700 mm from
# the mirror, their centres 130-300 px from the image centre. ``simulate_views`` draws
# such poses (rotation vector and translation, board frame to the camera frame C); we
# keep its poses and render an image for each.
truth_camera = {"xi": 1.134, "gamma_u": 317.8, "gamma_v": -318.0, "u0": 642.5, "v0": 522.9}
_, sim = bc.simulate_views(truth_camera, n_views=N_VIEWS, rng=1)
images, true_corners = [], []
for k, pose in enumerate(sim["poses"]):
    img, exact = bc.render_board(truth_camera, pose, noise=2.0, rng=k)
    images.append(img)
    true_corners.append(exact.pixels)

fig, ax = plt.subplots(figsize=(7, 5.6))
ax.imshow(images[0], cmap="gray")
ax.set_title("a rendered view (1280 x 1024)")

# %%
# OpenCV's detector, refined to sub-pixel. Each view is a ``BoardView``: the corners in the
# image (px) and on the board (mm). A chessboard looks alike from both sides and turned by
# 180 degrees, so we measure each detected corner against the nearest true one.
views = [bc.find_chessboard(img, board=(8, 6), square=42.0, name=f"view {k}")
         for k, img in enumerate(images)]
for v, t in zip(views, true_corners, strict=True):
    d = np.min(np.linalg.norm(v.pixels[:, None] - t[None], axis=-1), axis=1)
    print(f"{v.name}: {v.n_corners} corners, error rms {np.sqrt(np.mean(d ** 2)):.3f} px, "
          f"max {d.max():.3f} px")

ax.plot(*views[0].pixels.T, "r+", ms=6)
ax.set_xlim(views[0].pixels[:, 0].min() - 60, views[0].pixels[:, 0].max() + 60)
ax.set_ylim(views[0].pixels[:, 1].max() + 60, views[0].pixels[:, 1].min() - 60)

# %%
# The calibration: every view is used; one pose per view is integrated out of the
# intrinsics' covariance. The default noise model gives each view its own noise level and
# a smooth per-view systematic field: what real corners show, and what makes the stated
# covariance hold up under cross-validation on real views (:doc:`../camera`,
# :doc:`../camera_images`).
cam = bc.calibrate_camera(views)
print(cam.summary())
sd = cam.std()
print("error / sd: " + ", ".join(f"{n} {(v - truth_camera[n]) / sd[n]:+.2f}"
                                 for n, v in cam.intrinsics.items()))

# %%
# The result speaks the package's vocabulary: ``project`` and ``reconstruct`` rays with
# their covariances, ``save`` and ``bc.load_camera``. The corners can be kept as a file
# (CSV or NPZ) and calibrated again without the images (``bayescal calibrate-camera
# --corners corners.csv``).
import tempfile  # noqa: E402

with tempfile.TemporaryDirectory() as tmp:
    bc.write_views(os.path.join(tmp, "corners.csv"), views)
    again = bc.load_views(os.path.join(tmp, "corners.csv"))
    cam.save(os.path.join(tmp, "camera.json"))
    print(len(again), "views read back;", bc.load_camera(os.path.join(tmp, "camera.json")))

ray = np.array([[0.6, 0.0, -0.8]])              # a direction 37 degrees below the horizon
uv, cov = cam.project(ray, return_cov=True)
print(f"it images at {uv[0].round(2)} px, sd {np.sqrt(np.diag(cov[0])).round(3)} px")
