"""``bayescal extract`` over a sequence of frames: several images, a folder or a video.

One image runs :class:`~bayescal.cli.jobs.ExtractJob` as before (``laser.csv``,
``overlay.png``). Several frames run :class:`FramesJob`: the ring is followed from frame to
frame (:func:`bayescal.track_laser`), each frame's laser pixels go to ``laser/<frame>.csv``
(the columns of ``laser.csv``, which ``bayescal reconstruct laser/*.csv --run RUN`` reads as
one frame each) and ``frames.csv`` has a line per frame: whether it was followed, refused,
how many points, their median sd, the seconds it took.
"""

from __future__ import annotations

import pathlib
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from ..errors import BayescalError, ExtractionError, UsageError
from ..io.outputs import check_out
from . import options as op
from .jobs import ExtractJob, _opts, _read_image

__all__ = ["FramesJob", "build_extract", "run_extract", "run_frames"]


def _paths(images):
    paths = [pathlib.Path(p) for p in (images if isinstance(images, (list, tuple)) else [images])]
    for p in paths:
        if not p.exists():
            raise UsageError(f"IMAGE {p}: no such file or folder")
    return paths


def build_extract(**options):
    """The job of ``bayescal extract``: :class:`~bayescal.cli.jobs.ExtractJob` for one image
    file, :class:`FramesJob` for several, a folder or a video."""
    from ..image.read import VIDEO_SUFFIXES

    paths = _paths(options.get("image"))
    if len(paths) == 1 and paths[0].is_file() and paths[0].suffix.lower() not in VIDEO_SUFFIXES:
        return ExtractJob.build(**{k: v for k, v in options.items() if k != "no_progress"}
                                | {"image": paths[0]})
    return FramesJob.build(**options)


@dataclass(frozen=True)
class FramesJob:
    """Extract the laser pixels of every frame of a sequence (options as in
    :data:`~bayescal.cli.options.EXTRACT_OPTIONS`; ``image`` several files, a folder or a
    video)."""

    frames: object = field(repr=False)      # a folder, a video or a tuple of image files
    count: int | None
    background: np.ndarray | None = field(repr=False)
    center: tuple | None
    channel: int
    along_sd: float
    radius: tuple | None
    out: pathlib.Path
    force: bool = False
    progress: bool = True

    @classmethod
    def build(cls, **options):
        """Validated job: the frames named and counted, the laser-off image read, before
        anything is written."""
        from ..image.read import count_frames, frame_names

        o = _opts(op.EXTRACT_OPTIONS, options)
        paths = _paths(o["image"])
        if len(paths) > 1:
            bad = [p for p in paths if not p.is_file()]
            if bad:
                raise UsageError(f"IMAGE {bad[0]}: several IMAGEs must all be image files "
                                 "(give a folder or a video alone)")
        frames = paths[0] if len(paths) == 1 else tuple(paths)
        try:
            names, count = frame_names(frames), count_frames(frames)
        except (BayescalError, OSError) as exc:
            raise UsageError(f"IMAGE {paths[0]}: {exc}") from None
        twice = sorted({n for n in names or () if names.count(n) > 1})
        if twice:
            raise UsageError(f"IMAGE: two frames share a name ({', '.join(twice)}); each "
                             "frame's laser file is named after its image")
        inputs = [*paths] + ([o["background"]] if o["background"] is not None else [])
        check_out(o["out"], force=o["force"], inputs=inputs)
        bg = None if o["background"] is None else _read_image(o["background"], "--background",
                                                               o["channel"])
        return cls(frames=frames, count=count, background=bg,
                   center=None if o["center"] is None else tuple(map(float, o["center"])),
                   channel=o["channel"], along_sd=float(o["along_sd"]),
                   radius=op.radius_range(o["radius"]), out=pathlib.Path(o["out"]),
                   force=o["force"], progress=not o["no_progress"])


def run_extract(job, folder):
    """Run either job of ``bayescal extract``."""
    from .runs import run_extract as run_one

    return run_frames(job, folder) if isinstance(job, FramesJob) else run_one(job, folder)


def _frames(job):
    """``(name, image)`` per frame; an unreadable frame is bad input (exit 2)."""
    from ..image.read import iter_frames

    try:
        yield from iter_frames(job.frames, channel=job.channel)
    except (BayescalError, OSError) as exc:
        raise UsageError(f"frames: {exc}") from None


def run_frames(job, folder):
    """Follow the ring through the frames; write ``laser/<frame>.csv`` per frame and
    ``frames.csv``; a progress bar on stderr counts the frames followed, extracted anew and
    refused."""
    from tqdm.auto import tqdm

    from ..image.track import LaserTracker
    from .runs import write_laser_pixels

    tracker = LaserTracker(background=job.background, center=job.center, channel=job.channel,
                           along_sd=job.along_sd, radius=job.radius)
    sub, rows = folder.sub("laser"), []
    counts = {"followed": 0, "anew": 0, "refused": 0}
    with tqdm(total=job.count, desc="frames", unit="frame", file=sys.stderr,
              disable=not job.progress) as bar:
        for i, (name, img) in enumerate(_frames(job)):
            t0 = time.process_time()
            try:
                lp = tracker(img, name=name)
            except BayescalError as exc:         # a frame of another size, a bad array
                raise UsageError(f"frame {i} ({name}): {exc}") from None
            seconds = time.process_time() - t0
            if not lp.refused:
                how = "followed from the last frame" if lp.tracked else f"extracted ({lp.note})"
                sub.add(write_laser_pixels(sub.path / f"{name}.csv", lp, name,
                                           image_size=img.shape[1::-1],
                                           extra_note=f"\nframe {i}: {how}"))
            rows.append((name, lp, seconds))
            counts["refused" if lp.refused else "followed" if lp.tracked else "anew"] += 1
            bar.set_postfix(**counts, refresh=False)
            bar.update(1)
    _summary(job, folder, rows)


def _summary(job, folder, rows):
    """``frames.csv``, and the lines on the terminal; every frame refused is bad input."""
    from ..io.data import _write_csv

    refused = [(n, lp.error) for n, lp, _ in rows if lp.refused]
    if len(refused) == len(rows):
        err = refused[0][1] if refused else None
        raise ExtractionError(f"no frame has a plausible laser ring ({len(rows)} frames); the "
                              f"first: {err.reason if err is not None else 'no frames'}")
    lps = [lp for _, lp, _ in rows]
    sd = [float(np.nanmedian(lp.sd_normal[~lp.flagged])) if (~lp.flagged).any() else np.nan
          for lp in lps]
    notes = [f"frame {k}: {n} -> " + (f"refused: {lp.error.reason}" if lp.refused else
                                       f"laser/{n}.csv" + ("" if lp.tracked else f" ({lp.note})"))
             for k, (n, lp, _) in enumerate(rows)]
    _write_csv(folder.path / "frames.csv", {
        "frame": np.arange(len(rows)), "tracked": np.array([lp.tracked for lp in lps]),
        "refused": np.array([lp.refused for lp in lps]),
        "points": np.array([len(lp) for lp in lps]),
        "flagged": np.array([int(lp.flagged.sum()) for lp in lps]),
        "median_sd_px": np.array(sd), "cpu_seconds": np.array([r[2] for r in rows])},
        header_comment="bayescal extract: one line per frame (tracked: 1 = the ring followed "
        "from the last frame, 0 = the full extractor; refused: 1 = no plausible ring, no laser "
        "file)\n" + "\n".join(notes))
    folder.add(folder.path / "frames.csv")
    for n, err in refused:
        print(f"bayescal: warning: frame {n} refused (no laser file): {err.reason}",
              file=sys.stderr)
    followed = sum(lp.tracked for lp in lps)
    print(f"{len(rows)} frames: {followed} followed from the last, "
          f"{len(rows) - followed - len(refused)} extracted anew, {len(refused)} refused; "
          f"wrote {job.out / 'laser'}/<frame>.csv and {job.out / 'frames.csv'}")
