"""Frames in, poses out: Odometry / track, the keyframe policy, the static/dynamic segmentation, batches."""
