"""Every name that ``jaxvo`` exports stays importable from the top-level package."""
from __future__ import annotations

import pytest

import jaxvo

# the public API as exported before the package layout was redesigned; names are added, never removed
PUBLIC = [
    "geometry", "Camera", "camera_for_sequence", "PRESETS", "TUM_FR1", "TUM_FR2", "TUM_FR3", "BONN", "DEFAULT",
    "Frame", "make_frame", "METHODS", "Config", "MotionEstimate", "Track", "TrackConfig", "TrackStep",
    "estimate_motion", "track", "Odometry",
    "DatasetError", "TumSequence", "IclNuimSequence", "RedwoodSequence", "open_sequence", "TrajectoryWriter",
    "read_tum_trajectory", "write_tum_trajectory",
    "rpe", "ate", "mask_scores",
    "RunResult", "run_sequence", "load_config", "load_sequence", "evaluate", "trajectory_errors",
    "HindsightParams", "hindsight_masks",
]


@pytest.mark.parametrize("name", PUBLIC)
def test_public_name_is_exported(name):
    assert name in jaxvo.__all__
    assert getattr(jaxvo, name) is not None


def test_all_names_resolve():
    missing = [n for n in jaxvo.__all__ if not hasattr(jaxvo, n)]
    assert not missing, missing
