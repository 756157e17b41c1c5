"""Trajectories against ground truth: RPE / ATE / mask scores, the evaluation of a run, the OpenCV / Open3D peers."""
