"""Recordings on disk: sequence readers, calibration, masks, TUM trajectories, safe outputs.

One module per concept: :mod:`~jaxvo.data.layouts` finds sequence folders and opens them with
the reader of their layout (:mod:`~jaxvo.data.tum`, :mod:`~jaxvo.data.icl_nuim`,
:mod:`~jaxvo.data.redwood`); :mod:`~jaxvo.data.calibration` gives intrinsics and checks the depth
scale; :mod:`~jaxvo.data.textfiles` reads TUM frame lists and pose files;
:mod:`~jaxvo.data.stamps` matches timestamps; :mod:`~jaxvo.data.groundtruth` reads ground truth
(Bonn marker poses to camera poses); :mod:`~jaxvo.data.masks` reads mask images;
:mod:`~jaxvo.data.trajectory` chains and writes trajectories; :mod:`~jaxvo.data.outputs` writes
outputs safely. Every problem with the input raises :class:`DatasetError`.
"""
from jaxvo.data.errors import DatasetError
from jaxvo.data.textfiles import read_file_list, read_pose_file
from jaxvo.data.stamps import associate, interpolate_poses
from jaxvo.data.groundtruth import T_M_BONN, T_ROS, bonn_marker_to_camera, is_bonn_sequence, read_groundtruth
from jaxvo.data.calibration import (DEFAULT_SCALE_MIN_MEDIAN, PLAUSIBLE_DEPTH, check_depth_scale, read_calibration,
                                    sequence_camera)
from jaxvo.data.masks import load_mask, load_mask_of_size, match_masks, read_frame_mask, read_mask_dir, true_masks
from jaxvo.data.tum import TumSequence
from jaxvo.data.icl_nuim import IclNuimSequence
from jaxvo.data.redwood import RedwoodSequence
from jaxvo.data.layouts import data_root, find_sequence, find_sequences, is_sequence_dir, open_sequence
from jaxvo.data.trajectory import (HEADER, HELD_MARK, TrajectoryWriter, chain, format_pose_line, read_held,
                                   read_tum_trajectory, write_tum_trajectory)
from jaxvo.data.outputs import check_output, check_output_folder, finish, partial_path

__all__ = [
    "DatasetError", "TumSequence", "IclNuimSequence", "RedwoodSequence", "open_sequence", "sequence_camera",
    "check_depth_scale", "read_calibration", "associate", "read_file_list", "read_groundtruth",
    "read_pose_file", "bonn_marker_to_camera", "is_bonn_sequence", "interpolate_poses",
    "find_sequences", "find_sequence", "is_sequence_dir", "data_root", "T_ROS", "T_M_BONN",
    "PLAUSIBLE_DEPTH", "DEFAULT_SCALE_MIN_MEDIAN",
    "read_mask_dir", "true_masks", "load_mask", "load_mask_of_size", "match_masks", "read_frame_mask",
    "chain", "read_tum_trajectory", "write_tum_trajectory", "format_pose_line", "TrajectoryWriter", "HEADER",
    "HELD_MARK", "read_held",
    "check_output", "check_output_folder", "partial_path", "finish",
]
