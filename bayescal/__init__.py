"""bayescal: probabilistic calibration of a structured-light catadioptric stereo sensor.

A camera looks into a parabolic mirror; below it, on the same axis, a laser
cone lights the walls. bayescal calibrates the eight sensor parameters from
laser pixels and approximate 3D points (the paper's simultaneous method), the
classical way (sequential), and as a Bayesian posterior with emcee.

See ``docs/`` for the model, conventions and the public API.
"""

from .checks.compare import ModelComparison, compare_models
from .checks.fit import NoiseCollapseError, NoiseUndeterminedWarning, OffPlanWarning
from .checks.inputs import DuplicateRowsWarning
from .checks.misfit import ModelMisfitWarning
from .errors import BayescalError, BayescalWarning, DegenerateInputError, ExtractionError
from .fit.camera import calibrate_camera
from .fit.sequential import calibrate_sequential, sequential_residuals
from .fit.simultaneous import calibrate_simultaneous
from .image.chessboard import board_extent, find_chessboard
from .image.extract import LaserPixels, extract_laser
from .image.read import read_image
from .image.ringcv import RingCV, ring_cross_validation
from .image.track import LaserTracker, TrackedPixels, track_laser
from .image.views import BoardView, board_points
from .io.boards import load_views, write_views
from .likelihood.priors import Prior, default_pose_prior, default_prior
from .mcmc.camera import sample_camera_posterior
from .mcmc.sampling import NotConvergedError, NotConvergedWarning, sample_posterior
from .results.calibration import (
    CalibrationResult,
    ConvergenceError,
    IdentifiabilityReport,
    identifiability_report,
    load_result,
)
from .results.camera import CameraResult, load_camera
from .results.metrics import reconstruction_error, reconstruction_errors
from .results.posterior import Posterior, load_posterior
from .results.reconstruction import (
    LinearReconstruction,
    Reconstruction,
    Reconstructor,
    reconstruct_frames,
)
from .scene.board_render import render_board
from .scene.boards import simulate_views
from .scene.floorplan import FloorPlan
from .scene.render import RenderTruth, render_image
from .scene.sequence import render_sequence
from .scene.simulate import CalibrationData, Dataset, room_walls, simulate_room
from .sensor.camera import backproject, project
from .sensor.laser import cone_point, pixel_azimuth, triangulate, triangulate_plane
from .sensor.parameters import IDENTIFIABLE_NAMES, PARAM_NAMES, SensorParams
from .sensor.pose import POSE_NAMES, LaserPose

__version__ = "0.1.0"

__all__ = [
    "simulate_views",
    "sample_camera_posterior",
    "calibrate_camera",
    "CameraResult",
    "load_camera",
    "PARAM_NAMES",
    "IDENTIFIABLE_NAMES",
    "POSE_NAMES",
    "SensorParams",
    "LaserPose",
    "project",
    "backproject",
    "triangulate",
    "triangulate_plane",
    "cone_point",
    "pixel_azimuth",
    "simulate_room",
    "room_walls",
    "Dataset",
    "FloorPlan",
    "CalibrationData",
    "calibrate_sequential",
    "sequential_residuals",
    "CalibrationResult",
    "ConvergenceError",
    "IdentifiabilityReport",
    "identifiability_report",
    "reconstruction_error",
    "reconstruction_errors",
    "calibrate_simultaneous",
    "sample_posterior",
    "Posterior",
    "Reconstruction",
    "LinearReconstruction",
    "Reconstructor",
    "reconstruct_frames",
    "load_posterior",
    "load_result",
    "Prior",
    "default_prior",
    "default_pose_prior",
    "compare_models",
    "ModelComparison",
    "NotConvergedWarning",
    "NotConvergedError",
    "DuplicateRowsWarning",
    "OffPlanWarning",
    "ModelMisfitWarning",
    "NoiseCollapseError",
    "NoiseUndeterminedWarning",
    "BayescalError",
    "BayescalWarning",
    "DegenerateInputError",
    "ExtractionError",
    "render_image",
    "RenderTruth",
    "extract_laser",
    "track_laser",
    "LaserTracker",
    "TrackedPixels",
    "render_sequence",
    "read_image",
    "LaserPixels",
    "ring_cross_validation",
    "RingCV",
    "BoardView",
    "board_points",
    "find_chessboard",
    "board_extent",
    "render_board",
    "load_views",
    "write_views",
]
