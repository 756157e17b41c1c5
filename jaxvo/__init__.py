"""jaxvo: robust dense RGB-D visual odometry in JAX.

The library in ten lines::

    import jax, jaxvo
    seq = jaxvo.open_sequence("rgbd_dataset_freiburg2_desk")         # lazy frames, any layout
    cfg = jaxvo.Config(method="ransac")                              # or "classic", "huber"
    ref, cur = seq.frame(0), seq.frame(1)
    est = jaxvo.estimate_motion(ref, cur, seq.camera, cfg, jax.random.key(0))
    est.T_cur_ref      # (4, 4): reference-camera points -> current camera
    est.inlier_mask    # (480, 640) bool, False on moving / unexplained pixels
    traj = jaxvo.track((f for _, f in seq), seq.camera, cfg, jax.random.key(0))
    traj.poses         # (N, 4, 4) float64 T_world_cam, first frame = identity

Conventions: twist xi = (w, v) (rotation first); ``T_cur_ref`` maps points of
the reference (earlier) camera into the current one; trajectories are
``T_world_cam`` (camera-to-world, as in TUM files); intensity 0-255, depth in
metres (0 = invalid); pixels u = column, v = row, centres at integers.

Compiled programs are kept in ``$JAXVO_CACHE_DIR`` (default ``~/.cache/jaxvo``;
``JAXVO_CACHE_DIR=off`` turns it off, ``jaxvo.cache.enable(DIR)`` / ``jaxvo.cache.disable()``
do it from a program): a later process loads them instead of compiling (:mod:`jaxvo.runtime.cache`).

The packages, in data-flow order (each imports only from those before it):
:mod:`jaxvo.estimator` (two frames in, one :class:`MotionEstimate` out),
:mod:`jaxvo.tracking` (frames in, poses out), :mod:`jaxvo.data` (recordings, trajectories and
outputs on disk), :mod:`jaxvo.synthetic` (generated scenes), :mod:`jaxvo.evaluation` (errors
against ground truth, peers), :mod:`jaxvo.pipelines` (what each command does) and
:mod:`jaxvo.cli` (the command line), over the maths and settings at the top level
(:mod:`jaxvo.geometry`, :mod:`jaxvo.camera`, :mod:`jaxvo.frame`, :mod:`jaxvo.config`).
"""
# the persistent compilation cache, on unless JAXVO_CACHE_DIR=off: before anything compiles,
# so that every program is kept; jaxvo.cache.enable(DIR) / disable() move it or turn it off
from jaxvo.runtime import cache

cache.use_default()
# maths, intrinsics, frames, settings
from jaxvo import geometry
from jaxvo.camera import BONN, DEFAULT, PRESETS, TUM_FR1, TUM_FR2, TUM_FR3, Camera, camera_for_sequence
from jaxvo.config import METHODS, Config, TrackConfig
from jaxvo.frame import Frame, make_frame
# estimator: two frames in, one estimate out
from jaxvo.estimator import MotionEstimate, TrustStats, estimate_motion, explain_validity
# tracking: frames in, poses out
from jaxvo.tracking.hindsight import HindsightParams, sequence_masks as hindsight_masks
from jaxvo.tracking.odometry import Odometry, Track, TrackStep, track
# data: recordings and trajectories on disk
from jaxvo.data import DatasetError, IclNuimSequence, RedwoodSequence, TumSequence, open_sequence
from jaxvo.data.trajectory import TrajectoryWriter, read_tum_trajectory, write_tum_trajectory
# evaluation: errors against ground truth
from jaxvo.evaluation.metrics import ate, mask_scores, rpe
from jaxvo.evaluation.scoring import evaluate, trajectory_errors
# pipelines: what the commands do
from jaxvo.pipelines.run import RunResult, run_sequence
from jaxvo.pipelines.sequences import load_sequence
from jaxvo.pipelines.settings import load_config

__all__ = [
    "cache", "geometry", "Camera", "camera_for_sequence", "PRESETS", "TUM_FR1", "TUM_FR2", "TUM_FR3", "BONN",
    "DEFAULT",
    "METHODS", "Config", "TrackConfig", "Frame", "make_frame",
    "MotionEstimate", "TrustStats", "estimate_motion", "explain_validity",
    "Odometry", "Track", "TrackStep", "track", "HindsightParams", "hindsight_masks",
    "DatasetError", "TumSequence", "IclNuimSequence", "RedwoodSequence", "open_sequence",
    "TrajectoryWriter", "read_tum_trajectory", "write_tum_trajectory",
    "rpe", "ate", "mask_scores", "evaluate", "trajectory_errors",
    "RunResult", "run_sequence", "load_config", "load_sequence",
]
__version__ = "0.1.0"
