"""Tests of jaxvo.viz: overlays and figures from plain arrays."""
from __future__ import annotations

import numpy as np
import pytest

from jaxvo import viz


def test_outlier_overlay_colours():
    img = np.full((4, 6), 100.0)
    inl = np.zeros((4, 6), bool)
    inl[:, :3] = True
    val = np.ones((4, 6), bool)
    val[0, 5] = False
    o = viz.outlier_overlay(img, inl, val)
    assert o.shape == (4, 6, 3) and o.dtype == np.uint8
    assert o[1, 0, 2] > o[1, 0, 1]          # inliers: blue dominates
    assert o[1, 5, 1] > o[1, 5, 2]          # outliers: green dominates
    assert tuple(o[0, 5]) == (100, 100, 100)  # invalid: grey


def test_outlier_overlay_resizes_coarse_masks():
    img = np.zeros((8, 8))
    inl = np.array([[True, False], [False, True]])
    o = viz.outlier_overlay(img, inl)
    assert o.shape == (8, 8, 3)
    assert o[0, 0, 2] > o[0, 0, 1] and o[0, 7, 1] > o[0, 7, 2]


def test_top_view_axes():
    p = np.zeros((10, 3))
    p[:, 0] = np.linspace(0, 1, 10)
    p[:, 2] = np.linspace(0, 0.5, 10)
    assert viz.top_view_axes(p) == (0, 2)
    T = np.tile(np.eye(4), (10, 1, 1))
    T[:, :3, 3] = p
    assert viz.top_view_axes(T) == (0, 2)
    with pytest.raises(ValueError):
        viz.top_view_axes(np.zeros((3, 2)))


def test_figures_are_written(tmp_path):
    t = np.linspace(0, 2, 20)
    gt = np.stack([np.cos(t), np.sin(t), 0 * t], 1)
    est = gt + 0.01
    f = viz.plot_trajectories({"groundtruth": gt, "classic": est, "ransac": gt})
    p = viz.save_figure(f, tmp_path / "traj.png")
    assert p.stat().st_size > 5000
    f = viz.plot_errors_over_time({"classic": t, "ransac": t}, {"classic": t * 0.01, "ransac": t * 0.001})
    assert viz.save_figure(f, tmp_path / "err.png").stat().st_size > 5000
    f = viz.plot_eval(gt, est, t[1:], np.diff(t), t, np.full(20, 0.01))
    assert viz.save_figure(f, tmp_path / "eval.pdf").stat().st_size > 1000
    f = viz.plot_overlay(np.zeros((20, 30)), np.ones((20, 30), bool), true_moving=np.eye(20, 30, dtype=bool))
    assert viz.save_figure(f, tmp_path / "ov.png").stat().st_size > 1000
    viz.save_image(np.zeros((5, 5, 3), np.uint8), tmp_path / "img.png")
    assert (tmp_path / "img.png").is_file()


@pytest.mark.parametrize("names", [["groundtruth", "classic", "huber", "ransac", "frame-to-frame"],
                                   ["classic", "huber", "ransac", "a", "b", "c"], ["x", "y", "ransac", "z"]])
def test_every_method_of_a_plot_gets_its_own_colour(names):
    t = np.linspace(0, 1, 5)
    f = viz.plot_errors_over_time({n: t for n in names}, {n: t * k for k, n in enumerate(names)})
    colours = [line.get_color() for line in f.axes[0].get_lines()]
    assert len(set(colours)) == len(names), colours
    f = viz.plot_trajectories({n: np.stack([t, t * k, 0 * t], 1) for k, n in enumerate(names)})
    colours = [line.get_color() for line in f.axes[0].get_lines()[::2]]     # curve, start marker
    assert len(set(colours)) == len(names), colours


def test_saved_figures_keep_their_axis_labels(tmp_path):
    """A long title or label is not clipped: the saved area grows to hold it (wider than the figure)."""
    import matplotlib.image as mpimg

    t = np.linspace(0, 2, 20)
    f = viz.plot_trajectories({"groundtruth": np.stack([t, 0 * t, t], 1)}, title="a title " * 12)
    assert f.axes[0].get_ylabel() == "z [m]"
    w = f.get_size_inches()[0] * 120
    img = mpimg.imread(viz.save_figure(f, tmp_path / "t.png"))
    assert img.shape[1] > w
