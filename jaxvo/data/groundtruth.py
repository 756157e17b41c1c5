"""Ground truth of a sequence folder: ``groundtruth.txt`` as ``T_world_cam``.

The Bonn RGB-D Dynamic dataset stores the pose of the motion-capture marker, not of the camera;
:func:`bonn_marker_to_camera` applies the published fixed transforms (``data/bonn/README.md``)
so that ground truth is always ``T_world_cam`` (camera-to-world, camera frame x right, y down,
z forward).
"""
from __future__ import annotations

from pathlib import Path
from typing import Tuple

import numpy as np

from jaxvo import geometry
from jaxvo.data.textfiles import read_pose_file

__all__ = ["read_groundtruth", "bonn_marker_to_camera", "is_bonn_sequence", "T_ROS", "T_M_BONN"]


#: Fixed change of axes used by the Bonn dataset (a permutation with det +1).
T_ROS = np.array([[-1.0, 0.0, 0.0, 0.0],
                  [0.0, 0.0, 1.0, 0.0],
                  [0.0, 1.0, 0.0, 0.0],
                  [0.0, 0.0, 0.0, 1.0]])

#: Bonn marker-to-camera calibration as published (its 3x3 block is 1.059 x a rotation).
T_M_BONN = np.array([[1.0157, 0.1828, -0.2389, 0.0113],
                     [0.0009, -0.8431, -0.6413, -0.0098],
                     [-0.3009, 0.6147, -0.8085, 0.0111],
                     [0.0, 0.0, 0.0, 1.0]])


def bonn_marker_to_camera(T_gt) -> np.ndarray:
    """Bonn ground-truth marker poses (..., 4, 4) -> camera poses T_world_cam (..., 4, 4) float64.

    ``T_cam = T_ros @ T_gt @ T_ros @ T_m`` (``data/bonn/README.md``), then the rotation
    block is projected onto SO(3) (the published ``T_m`` has a 1.059-scaled rotation; the
    translation is unaffected by that scale). The resulting world frame is y-up.
    """
    T = T_ROS @ np.asarray(T_gt, dtype=np.float64) @ T_ROS @ T_M_BONN
    T = np.array(T, dtype=np.float64, copy=True)
    T[..., :3, :3] = geometry.project_to_so3(T[..., :3, :3])
    T[..., 3, :] = (0.0, 0.0, 0.0, 1.0)
    return T


def is_bonn_sequence(path) -> bool:
    """True for a folder named ``rgbd_bonn_*`` (Bonn RGB-D Dynamic dataset)."""
    return Path(path).name.lower().startswith("rgbd_bonn_")


def read_groundtruth(path, bonn: bool = False) -> Tuple[np.ndarray, np.ndarray]:
    """Read ``groundtruth.txt`` -> (timestamps (N,) float64, T_world_cam (N, 4, 4) float64).

    With ``bonn=True`` the marker poses are converted to camera poses
    (:func:`bonn_marker_to_camera`).
    """
    t, T = read_pose_file(path, what="ground-truth")
    if bonn:
        T = bonn_marker_to_camera(T)
    return t, T
