"""``bayescal demo`` (simulate; calibrate from a rendered image of the laser on the floor
plan, three ways from the simulated points and from the floor plan; report) and
``bayescal study``.

The demo builds the same :class:`~bayescal.cli.jobs.CalibrateJob` objects as the
``calibrate`` command (through :meth:`CalibrateJob.build`, so every input check
runs) and writes an index built with the report's document structure, with the
figures of each method.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import os
import subprocess
import sys

import numpy as np

from ..errors import Failure
from ..report.document import Document, write_document
from .jobs import CalibrateJob
from .matching import IMAGE_TRUTH_NOTE, true_points
from .runs import run_calibrate, write_laser_pixels, write_simulation

__all__ = ["run_demo", "run_study", "off_design_sensor", "DEMO_ROOM", "OFF_NOMINAL_SCALE"]

#: the paper's large room (Fig. 9 protocol, 5 % approximate points)
DEMO_ROOM = {"range_mm": 5000.0, "n_walls": 7, "sigma_px": 0.1, "approx_error": 0.05,
             "approx_model": "fig9"}
#: the demo's true sensor is the design drawn off by this many default-prior sds
OFF_NOMINAL_SCALE = 0.5
#: sd along the ring given to the extracted pixels of the image stage, px: a floor plan
#: takes each point's azimuth from its pixel, and the extractor's default 5 px left the
#: least squares at 212 mm mean error in the demo room (1 px: 114 mm; docs/images.md)
IMAGE_ALONG_SD = 1.0


def off_design_sensor(rng, *, scale=OFF_NOMINAL_SCALE):
    """The paper's (design) sensor perturbed by ``scale`` x the default prior sd, per parameter.

    A truth equal to the design values the priors are centred on would flatter
    every parameter the prior holds; the studies and the demo draw it off.
    """
    from ..likelihood.priors import default_prior
    from ..sensor.parameters import PARAM_NAMES, SensorParams

    prior = default_prior()
    sd = np.array([prior[n].std() for n in PARAM_NAMES])
    return SensorParams.from_array(SensorParams.paper().to_array()
                                   + scale * sd * rng.standard_normal(8))


def _simulate(job):
    from ..scene.simulate import simulate_room

    rng = np.random.default_rng(job.seed)
    truth = off_design_sensor(rng)
    return simulate_room(truth, n_points=job.n_points, rng=rng, **DEMO_ROOM)


@contextlib.contextmanager
def _said_as_final(staged, final):
    """Warnings given inside: the staged folder named as the final one, and the options the
    demo chose (``--walls``: its floor plan) as what they are, not as the user's."""
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    for w in caught:
        text = str(w.message).replace(staged, final).replace(
            "with --walls", "with a floor plan (the demo's data/walls.csv)")
        warnings.warn_explicit(text, w.category, w.filename, w.lineno)


def _calibrate_one(job, root, method, *, stage=None, files=None, figures=()):
    """One calibration into ``root/stage``; stage "floorplan" calibrates from walls.csv.

    ``files`` replaces the input files (``data``, ``truth``, ``walls``, ...); ``figures``
    (caption, path) go into the stage's report.
    """
    stage = stage or method
    sub = root.sub(stage)
    data = root.path / "data"
    scene = ({"walls": data / "walls.csv"} if stage == "floorplan"
             else {"calibration": data / "calibration.npz"})
    files = files or {"data": data / "laser.csv", "truth": data / "truth.json", **scene}
    said = io.StringIO()
    staged, final = str(root.path.resolve()), str(job.out.resolve())
    with contextlib.redirect_stdout(said), _said_as_final(staged, str(job.out)):
        cjob = CalibrateJob.build(method=method, seed=job.seed, max_steps=job.max_steps,
                                  no_progress=not job.progress,
                                  allow_unconverged=job.allow_unconverged,
                                  out=job.out / stage, force=True,
                                  title=f"bayescal demo: {stage}", **files)
    print(said.getvalue().replace(staged, str(job.out)), end="")
    cjob = dataclasses.replace(cjob, inputs={k: v.replace(staged, final)
                                             for k, v in cjob.inputs.items()},
                               figures=tuple(figures))
    status, err = "ok", "-"
    try:
        failed, acc = run_calibrate(cjob, sub)
    except Failure as exc:
        failed, acc = str(exc), None
    if failed:
        status = "NOT CONVERGED" if "did not converge" in failed else f"failed: {failed}"
        print(f"bayescal: {failed}", file=sys.stderr)
    if acc:
        err = f"{acc['mean_error_mm']:.1f}"
    report = f"{stage}/report.html" if (sub.path / "report.html").is_file() else None
    return {"stage": stage, "status": status, "error": err, "report": report,
            "folder": sub.path}


def _image_inputs(job, root, ds):
    """Render the room's laser image and its laser-off image (``data/``), extract the laser
    (``image/laser.csv``, as ``bayescal extract``: calibrate leaves its flagged rows out) and
    write the truth of its unflagged pixels (``image/truth.json``) and the extraction
    overlay. Returns (files, figures)."""
    import imageio.v3 as iio

    from ..image.extract import extract_laser
    from ..io.data import write_json
    from ..plotting.basic import savefig
    from ..plotting.image import plot_laser_overlay
    from ..scene.render import render_image

    data, sub = root.sub("data"), root.sub("image")
    img, tr = render_image(ds.params, ds.walls, n_lamps=2, ghost=0.3, bits=16,
                           with_background=True, rng=job.seed)
    iio.imwrite(data.path / "laser_image.png", img)
    iio.imwrite(data.path / "laser_off.png", tr.background)
    data.add(data.path / "laser_image.png", data.path / "laser_off.png")
    lp = extract_laser(img, background=tr.background, along_sd=IMAGE_ALONG_SD)
    k = ~lp.flagged
    print(f"extracted {len(lp)} laser pixels from data/laser_image.png ({int(k.sum())} "
          f"unflagged, median sd across the ring {np.median(lp.sd_normal[k]):.3f} px)")
    laser = write_laser_pixels(sub.path / "laser.csv", lp, "laser_image.png",
                               extra_note=f" (along_sd {IMAGE_ALONG_SD:g} px)",
                               image_size=img.shape[1::-1])
    truth = sub.path / "truth.json"
    write_json(truth, {"params": ds.params.as_dict(), "walls": ds.walls,
                       "points": _true_points(ds.params, lp.pixels[k], tr),
                       "n_points": int(k.sum()), "accuracy_note": IMAGE_TRUTH_NOTE})
    overlay = savefig(plot_laser_overlay(img, lp), sub.path / "overlay.png")
    sub.add(laser, truth, sub.path / "overlay.png")
    # the covariances' global scale inferred: at 5000 mm they are ~1.2x too small
    # (docs/images.md), and the stage's model check fails with them as they are
    files = {"data": laser, "truth": truth, "walls": data.path / "walls.csv",
             "sigma_px": "infer"}
    return files, [("Laser extraction: the laser image with the extracted pixels (colour: "
                    "sd across the ring; red crosses: flagged, not used)", overlay)]


def _true_points(params, pixels, ring):
    """The true laser point (N, 3), mm, at each pixel's azimuth under the true sensor,
    interpolated on the renderer's true centre line ``ring`` (a RenderTruth)."""
    return true_points(params, pixels, ring.azimuth, ring.points)


def _index(out, rows, ds):
    doc = Document("bayescal demo: the paper's large room")
    doc.paragraph(f"Simulated {ds.n_points} laser points in a {ds.range_mm:.0f} mm room, pixel "
                  f"noise {ds.sigma_px:g} px, approximate points {100 * ds.approx_error:g} "
                  f"percent ({ds.approx_model} protocol); the true sensor is drawn "
                  f"{OFF_NOMINAL_SCALE:g} prior sd off the design values the priors are centred "
                  "on. Inputs in `data/`.")
    links = {r["report"]: r["report"] for r in rows if r["report"]}
    doc.table(["stage", "status", "mean 3D error (mm)", "report"],
              [[r["stage"], r["status"], r["error"], r["report"] or "-"] for r in rows],
              flags=[r["status"] != "ok" for r in rows], links=links)
    doc.paragraph("Paper (Fig. 9, 5 percent approximation, 5000 mm): simultaneous about 90 mm, "
                  "sequential about 310 mm mean error. The floorplan stage is the simultaneous "
                  "method from the room's rough floor plan (data/walls.csv, each wall off by "
                  "one draw of 5 percent) in place of the approximate points.")
    doc.paragraph("The image stage starts from a rendered camera image of the laser in the "
                  "same room (data/laser_image.png, with two lamps, a ghost reflection and a "
                  "laser-off image, data/laser_off.png): the extracted, unflagged pixels with "
                  "their per-point covariances (a global scale on them inferred), calibrated "
                  "by least squares on the same rough floor plan. Its error is against the "
                  "true laser point at each extracted pixel's azimuth (see its report).")
    for r in rows:
        png = r["folder"] / "reconstruction.png"
        if png.is_file():
            doc.figure(f"{r['stage']}: reconstruction", png)
    md, ht = write_document(doc, out, "index")
    # the Markdown refers to the figures by name: point it at the stage folders (the
    # report links already are)
    text = md.read_text(encoding="utf-8")
    for r in rows:
        text = text.replace(f"![{r['stage']}: reconstruction](reconstruction.png)",
                            f"![{r['stage']}: reconstruction]({r['stage']}/reconstruction.png)")
    md.write_text(text, encoding="utf-8")
    return md, ht


def run_demo(job, root):
    """Simulate the large room, calibrate it from a rendered image of its laser on the floor
    plan, three ways from the simulated points and from its rough floor plan, write the
    reports and the index.

    Returns
    -------
    str or None
        A failure message when a method did not converge.
    """
    ds = _simulate(job)
    print(f"simulated {ds.n_points} laser points, range {ds.range_mm:.0f} mm, sigma_px "
          f"{ds.sigma_px:g}, approx. points 5 percent, seed {job.seed}", flush=True)
    write_simulation(root.sub("data"), ds, seed=job.seed)
    rows = []
    if ds.floor_plan is not None:
        print("\n== image ==", flush=True)
        files, figures = _image_inputs(job, root, ds)
        rows.append(_calibrate_one(job, root, "simultaneous", stage="image", files=files,
                                   figures=figures))
    stages = [("sequential", None), ("simultaneous", None), ("bayes", None)]
    if ds.floor_plan is not None:
        stages.append(("simultaneous", "floorplan"))
    for method, stage in stages:
        print(f"\n== {stage or method} ==", flush=True)
        rows.append(_calibrate_one(job, root, method, stage=stage))
    root.add(*_index(root.path, rows, ds))
    print("\n" + "\n".join(f"{r['stage']:>12}: {r['status']}; mean 3D error {r['error']} mm"
                           for r in rows))
    print(f"open {job.out / 'index.html'}")
    bad = [r["stage"] for r in rows if r["status"] != "ok"]
    return f"not every method succeeded ({', '.join(bad)})" if bad else None


def run_study(job, folder):
    """Run the study script into the staging folder; a non-zero exit is a failure."""
    import shlex

    cmd = job.argv(folder.path)
    print("running " + " ".join(shlex.quote(c) for c in job.argv(job.out)), flush=True)
    # the script writes into the staging folder; it names the final one in its last line
    env = {**os.environ, "BAYESCAL_STUDY_SHOWN_OUT": str(job.out)}
    rc = subprocess.run(cmd, check=False, env=env).returncode
    if rc != 0:
        if rc < 0 or rc == 130:
            raise KeyboardInterrupt
        raise Failure(f"study {job.name} exited with code {rc}")
    for p in sorted(folder.path.rglob("*")):
        if p.is_file():
            folder.add(p)
