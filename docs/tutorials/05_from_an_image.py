"""
From an image to a calibration
==============================

A user of the sensor starts with camera images, not pixel lists. bayescal extracts the laser
ring with an uncertainty for every point (small across the ring, large along it); with
approximate points the least squares takes those covariances (``pixel_cov=``). Here the
image is rendered by the package's own renderer, so we know the truth.
"""

# %%
import numpy as np

import bayescal as bc

p = bc.SensorParams.paper()
ds = bc.simulate_room(p, range_mm=2500, n_points=50, n_walls=6, rng=4)

# %%
# An 800x600 image of the room with the laser on, two lamps and a ghost of the ring, and the
# same view with the laser off.
img, truth = bc.render_image(p, ds.walls, rng=0, with_background=True, n_lamps=2, ghost=0.3)
lp = bc.extract_laser(img, background=truth.background)
keep = ~lp.flagged
print(f"{keep.sum()} laser pixels kept, {lp.flagged.sum()} flagged as distractors")
sd_across = np.sqrt(np.linalg.eigvalsh(lp.covariance[keep])[:, 0])
print(f"median sd across the ring: {np.median(sd_across):.3f} px")

# %%
# The extracted points over the image, coloured by their sd across the ring.
import matplotlib.pyplot as plt  # noqa: E402

fig, ax = plt.subplots(figsize=(7, 5))
ax.imshow(img, cmap="gray")
sc = ax.scatter(*lp.pixels[keep].T, c=sd_across, s=4, cmap="viridis")
ax.plot(*lp.pixels[~keep].T, "rx", ms=4)
fig.colorbar(sc, ax=ax, label="sd across the ring (px)")
ax.set_xlim(250, 550)
ax.set_ylim(450, 150)

# %%
# Calibrate from the extracted pixels and the room's rough floor plan. Each ring point
# lies on some wall; the plan says roughly where the walls are. (A floor plan takes one
# pixel noise level for now, not the per-point covariances.) The errors, in sds:
res = bc.calibrate_simultaneous(lp.pixels[keep], ds.floor_plan, sigma_px=0.2,
                                raise_on_failure=False)
z = (res.params.to_identifiable() - p.to_identifiable()) / np.sqrt(
    np.diag(res.covariance_identifiable))
print(", ".join(f"{n} {v:+.2f}" for n, v in zip(bc.IDENTIFIABLE_NAMES, z, strict=True)))

# %%
# A real frame
# ------------
# Real ring-laser frames are kept beside the repository in ``../shared/data/pipe`` (a red
# ring laser in a 12-inch pipe seen by a fisheye camera; their licence is unknown, so none
# is copied into the package and no figure here shows their pixels). When the folder is
# there the rest of this tutorial reads one of them; otherwise it renders a stand-in, a red
# laser in a dark room, and says so.
import os  # noqa: E402
import pathlib  # noqa: E402

here = pathlib.Path(globals().get("__file__", "docs/tutorials/x.py")).resolve().parent
candidates = [pathlib.Path(os.environ.get("BAYESCAL_PIPE_DATA", "/nonexistent"))] + [
    d / ".." / "shared" / "data" / "pipe" for d in (here.parents[1], pathlib.Path.cwd())]
pipe = next((d for d in candidates if (d / "ring_061.png").is_file()), None)
if pipe is not None:
    frame = bc.read_image(pipe / "ring_061.png", raw=True)   # as the file holds it: RGB uint8
    print(f"real frame {frame.shape[1]}x{frame.shape[0]}")
else:
    print("NOTE: ../shared/data/pipe is not here; a rendered stand-in is used instead")
    dark, _ = bc.render_image(p, ds.walls, rng=1, ambient=0.0, texture=0.0)
    frame = np.stack([dark, 0.3 * dark, 0.3 * dark], axis=-1).astype(np.uint8)

# %%
# No hint is needed: the ring is found off the image's centre (the first pass's own path
# gives its circle), its colour checked (the light over +-4 px in green and blue is about a
# third of the red's in these frames), and every point measured with its covariance.
lp_real = bc.extract_laser(frame)
ok = ~lp_real.flagged
print(f"{len(lp_real)} points, {int((~ok).sum())} flagged, "
      f"median sd across the ring {np.median(lp_real.sd_normal[ok]):.3f} px")

# %%
# There is no truth for a real frame, but the ring is a smooth closed curve: the package's
# cross-validation leaves out blocks of azimuths (8 px of ring each, 3 px more either side),
# predicts them from a curve through their neighbours and compares each held-out point's
# miss with its stated sd. A z rms near 1 says the covariances are honest.
cv = bc.ring_cross_validation(lp_real)
print(cv.summary())

fig, ax = plt.subplots(figsize=(7, 2.5))
theta = np.degrees(np.arctan2(*(lp_real.pixels[cv.index] - lp_real.center).T[::-1]))
ax.plot(theta, cv.z, ".", ms=2)
ax.axhline(0, color="k", lw=0.5)
ax.set_xlabel("azimuth (deg)")
ax.set_ylabel("held-out z")

# %%
# Where the ring is faint over a lit wall, tell the extractor where to look: ``center`` and
# ``radius`` (``--center``/``--radius`` from the shell). A hint outranks the mirror's disc,
# and a refusal after hints says what was found there and why it is not a laser ring.
if pipe is not None:
    lit = bc.read_image(pipe / "lit_001.png", raw=True)
    lp_lit = bc.extract_laser(lit, center=(430, 295), radius=(170, 260))
    print(f"lit frame: {int((~lp_lit.flagged).sum())} of {len(lp_lit)} points kept")
    try:
        bc.extract_laser(bc.read_image(pipe / "noring_v2_001.png", raw=True))
    except bc.ExtractionError as exc:
        print("laser-off frame refused:", exc.reason)
