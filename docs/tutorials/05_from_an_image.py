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
