"""Recordings on disk: sequence readers, calibration, masks, TUM trajectories, safe outputs."""
