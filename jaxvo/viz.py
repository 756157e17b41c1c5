"""Plots and mask overlays (matplotlib, Agg backend: no display needed).

Every function takes plain arrays and returns a ``matplotlib.figure.Figure``
(or an image array); ``save_figure`` writes one to disk and closes it.

Conventions: positions are (N, 3) metres (the translation part of
``T_world_cam``), times are seconds, translational errors metres, rotational
errors degrees. Masks are (H, W) bool with True = outlier (or inlier, as named).
The "top view" of a trajectory is the plane of the two world axes along which
the reference (ground-truth) trajectory extends most, unless ``axes`` is given
(e.g. ``(0, 1)`` for x-y in a TUM motion-capture world whose z points up,
``(0, 2)`` for x-z in a camera-like y-down world).
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping, Optional, Tuple

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["top_view_axes", "plot_trajectories", "plot_errors_over_time", "plot_eval",
           "outlier_overlay", "plot_overlay", "save_figure", "save_image", "METHOD_COLOURS",
           "INLIER_COLOUR", "OUTLIER_COLOUR"]

AXIS_NAMES = "xyz"
METHOD_COLOURS = {"groundtruth": "black", "classic": "tab:red", "huber": "tab:orange", "ransac": "tab:blue",
                  "estimate": "tab:blue"}
#: Fig. 4 of the paper: inliers blue, outliers green (RGB, 0-255).
INLIER_COLOUR = (40, 90, 255)
OUTLIER_COLOUR = (40, 220, 40)


def _pos(p) -> np.ndarray:
    p = np.asarray(p, dtype=np.float64)
    if p.ndim == 3 and p.shape[1:] == (4, 4):
        p = p[:, :3, 3]
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"positions must be (N, 3) or poses (N, 4, 4), got shape {p.shape}")
    return p


def _colours(names) -> dict:
    """A distinct colour per name: METHOD_COLOURS' for the names it has, the other names the
    first of matplotlib's ten colours that no name of this plot uses yet."""
    out = {n: METHOD_COLOURS[n] for n in names if n in METHOD_COLOURS}
    free = [c for c in (f"tab:{c}" for c in ("blue", "orange", "green", "red", "purple", "brown", "pink", "gray",
                                              "olive", "cyan")) if c not in out.values()]
    for k, n in enumerate(n for n in names if n not in out):
        out[n] = free[k % len(free)] if free else f"C{k % 10}"
    return out


def top_view_axes(positions) -> Tuple[int, int]:
    """The two axes (sorted indices into x, y, z) along which ``positions`` (N, 3) extend most."""
    p = _pos(positions)
    ext = np.ptp(p, axis=0) if len(p) else np.zeros(3)
    a = sorted(int(i) for i in np.argsort(-ext, kind="stable")[:2])
    return a[0], a[1]


def plot_trajectories(trajectories: Mapping[str, np.ndarray], reference: Optional[str] = "groundtruth",
                      axes: Optional[Tuple[int, int]] = None, ax=None, title: str = "Trajectories (top view)"):
    """Top view of several trajectories.

    trajectories: name -> (N, 3) positions or (N, 4, 4) poses, all in the same world frame
      (align estimates to the ground truth first, e.g. with :func:`jaxvo.evaluation.metrics.ate`).
    reference: name whose extent picks the view plane (falls back to the first trajectory).
    axes: explicit (i, j) axis indices for the plot's horizontal and vertical axes.
    Returns the Figure. Start points are marked with a circle.
    """
    trajs = {k: _pos(v) for k, v in trajectories.items()}
    if not trajs:
        raise ValueError("plot_trajectories: no trajectory given")
    if axes is None:
        ref = trajs.get(reference) if reference in trajs else next(iter(trajs.values()))
        axes = top_view_axes(np.concatenate([ref] + [v for v in trajs.values()], 0)
                             if np.ptp(ref, axis=0).max() < 1e-3 else ref)
    i, j = axes
    fig = None
    if ax is None:
        fig, ax = plt.subplots(figsize=(5.5, 5))
    colours = _colours(list(trajs))
    for name, p in trajs.items():
        style = "--" if name == reference else "-"
        c = colours[name]
        ax.plot(p[:, i], p[:, j], style, color=c, lw=1.5, label=name)
        if len(p):
            ax.plot(p[0, i], p[0, j], "o", color=c, ms=4)
    ax.set_xlabel(f"{AXIS_NAMES[i]} [m]")
    ax.set_ylabel(f"{AXIS_NAMES[j]} [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=10)
    if fig is not None:
        fig.tight_layout()
    return fig if fig is not None else ax.figure


def plot_errors_over_time(times: Mapping[str, np.ndarray], errors: Mapping[str, np.ndarray],
                          ylabel: str = "translational error [m]", title: str = "Error over time",
                          ax=None, log: bool = False):
    """Error curves over time, one per method: ``times[name]`` (M,) s, ``errors[name]`` (M,)."""
    fig = None
    if ax is None:
        fig, ax = plt.subplots(figsize=(7, 3.5))
    colours = _colours(list(errors))
    for name in errors:
        t = np.asarray(times[name], dtype=np.float64)
        e = np.asarray(errors[name], dtype=np.float64)
        ax.plot(t, e, "-", color=colours[name], lw=1.3, label=name)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    if log:
        ax.set_yscale("log")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=10)
    if fig is not None:
        fig.tight_layout()
    return fig if fig is not None else ax.figure


def plot_eval(gt_positions, est_positions, rpe_times, rpe_trans, ate_times=None, ate_errors=None,
              rpe_label: str = "RPE trans [m]", axes: Optional[Tuple[int, int]] = None,
              title: str = ""):
    """The ``jaxvo eval`` figure: top view of ground truth and aligned estimate, and the
    translational drift (RPE per pair, plotted at the pair's end time) and, if given, the
    ATE per frame over time. Times in seconds relative to whatever origin the caller picks."""
    fig, (a0, a1) = plt.subplots(1, 2, figsize=(12, 4.8), gridspec_kw={"width_ratios": [1, 1.4]})
    plot_trajectories({"groundtruth": gt_positions, "estimate": est_positions}, axes=axes, ax=a0,
                      title="Top view (estimate aligned to ground truth)")
    a1.plot(np.asarray(rpe_times), np.asarray(rpe_trans), "-", color="tab:blue", lw=1.3, label=rpe_label)
    if ate_times is not None and ate_errors is not None:
        a1.plot(np.asarray(ate_times), np.asarray(ate_errors), "-", color="tab:gray", lw=1.0,
                label="ATE [m] (aligned)")
    a1.set_xlabel("time [s]")
    a1.set_ylabel("translational error [m]")
    a1.grid(True, alpha=0.3)
    a1.legend(fontsize=8)
    a1.set_title("Translational drift over time")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return fig


def outlier_overlay(intensity, inlier_mask, valid_mask=None, alpha: float = 0.55) -> np.ndarray:
    """(H, W, 3) uint8 RGB: the grey image with inliers tinted blue and outliers green (paper Fig. 4).

    intensity: (H, W) 0-255. inlier_mask: (H, W) bool (any size: resized to the image with
    nearest neighbour). valid_mask: pixels where the residuals are defined (default all);
    outliers = valid & ~inlier; invalid pixels stay grey.
    """
    g = np.clip(np.asarray(intensity, dtype=np.float32), 0, 255)
    H, W = g.shape
    inl = _resize_mask(inlier_mask, W, H)
    val = np.ones((H, W), bool) if valid_mask is None else _resize_mask(valid_mask, W, H)
    out = np.repeat(g[..., None], 3, axis=2)
    for m, c in ((inl & val, INLIER_COLOUR), (val & ~inl, OUTLIER_COLOUR)):
        out[m] = (1 - alpha) * out[m] + alpha * np.asarray(c, np.float32)
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def _resize_mask(mask, W: int, H: int) -> np.ndarray:
    m = np.asarray(mask).astype(bool)
    if m.shape == (H, W):
        return m
    import cv2
    return cv2.resize(m.astype(np.uint8), (W, H), interpolation=cv2.INTER_NEAREST).astype(bool)


def plot_overlay(intensity, inlier_mask, valid_mask=None, true_moving=None, title: str = ""):
    """Figure with the inlier/outlier overlay (and, if given, the true moving-pixel mask's outline)."""
    img = outlier_overlay(intensity, inlier_mask, valid_mask)
    H, W = img.shape[:2]
    fig, ax = plt.subplots(figsize=(W / 100 + 0.4, H / 100 + 0.6), dpi=100)
    ax.imshow(img)
    if true_moving is not None:
        tm = _resize_mask(true_moving, W, H)
        if tm.any():
            ax.contour(tm.astype(float), levels=[0.5], colors="red", linewidths=0.8)
    ax.set_axis_off()
    ax.set_title(title or "inliers blue, outliers green" + (", true moving pixels outlined red"
                                                           if true_moving is not None else ""), fontsize=8)
    fig.tight_layout()
    return fig


def save_figure(fig, path, dpi: int = 120) -> Path:
    """Save ``fig`` to ``path`` (format from the extension), close it, return the Path. The
    saved area grows to hold every label (``bbox_inches="tight"``): none is clipped."""
    path = Path(path)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return path


def save_image(img_rgb: np.ndarray, path) -> Path:
    """Write an (H, W, 3) uint8 RGB image as PNG."""
    import cv2

    path = Path(path)
    if not cv2.imwrite(str(path), np.ascontiguousarray(np.asarray(img_rgb)[..., ::-1])):
        raise OSError(f"{path}: could not write image")
    return path
