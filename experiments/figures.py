"""Figures from real frames: the segmentation and outliers on Bonn crowd (the paper's Fig. 4/7)
and the 3-D map with moving points coloured apart (Fig. 2).

Runs jaxvo's default odometry (``jaxvo.track`` with ``TrackConfig()``: keyframes and the
persistent static/dynamic segmentation) once along the sequence, seed 0, and writes

* ``bonn_segmentation.png``: reference frames where people cover much of the image; blue =
  inliers of the estimate, green = outliers or pixels the segmentation marks dynamic,
  grey = no depth / not seen in the current frame;
* ``bonn_hindsight.png``: the same reference frames with the masks decided in hindsight from
  the odometry's trajectory (``jaxvo masks``, :func:`jaxvo.tracking.hindsight.sequence_masks`: each frame
  against the frames up to 48 before and after it); green = moving, blue = the rest with depth;
* ``bonn_map.png``: the map preview (perspective and top view): reference frames, about every
  5th frame, back-projected with their estimated poses, the points on pixels the segmentation
  marked dynamic painted green (``jaxvo.pipelines.mapping.MOVING_COLOUR``), 1 cm voxels;
* with ``--ply PATH``, the coloured cloud as a PLY file (not kept in the repository: ~10 MB).

Example::

    python experiments/figures.py                         # Bonn crowd -> experiments/results/figures/
    python experiments/figures.py SEQ_DIR --frames 60,90,120 --out-dir /tmp/fig --ply /tmp/map.ply
"""
from __future__ import annotations

import argparse
from pathlib import Path

import common
import numpy as np  # noqa: E402

import jax  # noqa: E402
from jaxvo import viz
from jaxvo.tracking import hindsight
from jaxvo.frame import undistort_images  # noqa: E402
from jaxvo.data import ply  # noqa: E402
from jaxvo.pipelines import mapping  # noqa: E402
from jaxvo.config import Config, TrackConfig
from jaxvo.tracking.odometry import track  # noqa: E402

DEFAULT_SEQUENCE = "bonn/rgbd_bonn_crowd"


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("sequence", nargs="?", default=None,
                    help=f"TUM-layout sequence folder (default: data_root()/{DEFAULT_SEQUENCE})")
    ap.add_argument("--frames", default="60,90,120,150",
                    help="comma-separated frames to show (each shown as the reference it was estimated against)")
    ap.add_argument("--max-frames", type=int, default=None, help="use at most N frames")
    ap.add_argument("--every", type=int, default=5, help="map: every N-th frame")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out-dir", default=str(common.RESULTS / "figures"))
    ap.add_argument("--ply", default=None, help="also write the map as this PLY file")
    return ap.parse_args(argv)


def main(argv=None):
    args = parse_args(argv)
    path = Path(args.sequence) if args.sequence else common.datasets.data_root() / DEFAULT_SEQUENCE
    if not path.is_dir():
        raise SystemExit(common.missing_data_message())
    seq = common.open_sequence(path, args.max_frames)
    frames = common.load_frames(seq)
    show = [int(x) for x in args.frames.split(",") if x.strip()]
    show = [j for j in show if 0 < j < len(frames)] or [len(frames) - 1]
    dynamic = {}          # reference index -> (H, W) bool marked dynamic when it served
    panels = {}

    def keep(step):
        if step.static_mask is not None:
            dynamic[step.reference] = ~step.static_mask
        if step.frame in show:
            # the estimate's masks at the frame's size (a calm estimate's lie at a coarser level)
            h, w = frames[step.reference].intensity.shape
            out, valid = mapping.outlier_mask(step.estimate, w, h, valid_too=True)
            static = np.ones((h, w), bool) if step.static_mask is None else np.asarray(step.static_mask, bool)
            inl = valid & ~out & static
            val = valid | ~static
            panels[step.frame] = (step.reference, viz.outlier_overlay(frames[step.reference].intensity, inl, val))

    tr = track(frames, seq.camera, Config(), jax.random.key(args.seed), policy=TrackConfig(), callback=keep)
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tiles = [panels[j][1] for j in show if j in panels]
    rows = [np.concatenate(tiles[i:i + 2] + [np.full_like(tiles[0], 255)] * (2 - len(tiles[i:i + 2])), 1)
            for i in range(0, len(tiles), 2)]
    grid = np.concatenate(rows, 0)
    p1 = viz.save_image(grid[::2, ::2], out / "bonn_segmentation.png")
    shown_refs = [panels[j][0] for j in show if j in panels]
    common.log(f"wrote {p1} (reference frames {shown_refs})")
    # the held frames' poses are guesses: no views (as jaxvo masks leaves out '# held' poses)
    known = np.where(np.concatenate([[True], tr.valid])[:, None, None], tr.poses, np.nan)
    moving = dict(hindsight.sequence_masks(seq.frame, known, seq.camera, frames=sorted(set(shown_refs))))
    tiles = [viz.outlier_overlay(frames[i].intensity, ~moving[i], np.asarray(frames[i].depth) > 0) for i in shown_refs]
    grid = np.concatenate([np.concatenate(tiles[i:i + 2] + [np.full_like(tiles[0], 255)] * (2 - len(tiles[i:i + 2])), 1)
                           for i in range(0, len(tiles), 2)], 0)
    p1 = viz.save_image(grid[::2, ::2], out / "bonn_hindsight.png")
    common.log(f"wrote {p1} (moving in hindsight: {', '.join(f'{moving[i].mean():.1%}' for i in shown_refs)})")

    # map frames: reference frames (they carry a segmentation), about every `every`-th frame
    refs = sorted(dynamic)
    used = refs[:: max(1, round(args.every * len(refs) / len(frames)))]
    clouds = []
    for i in used:
        bgr, dep = undistort_images(*seq.read_images(i), seq.camera, seq.lens)
        P, C, (r, c) = mapping.backproject_frame(np.ascontiguousarray(bgr[..., ::-1]),
                                                 dep.astype(np.float64) / seq.depth_scale, seq.camera,
                                                 tr.poses[i], 4.0, 2)
        mv = dynamic[i][r, c]
        clouds.append(mapping.PointCloud(P.astype(np.float32), C, mv))
    raw = mapping.PointCloud.concat(clouds)
    pts, cols, mv = mapping.voxel_downsample(raw.points, raw.colors, 0.01, raw.moving)
    cols = np.where(mv[:, None], np.asarray(mapping.MOVING_COLOUR, np.uint8), cols)
    p2 = mapping.render_preview(pts, cols, out / "bonn_map.png", poses=tr.poses)
    common.log(f"wrote {p2} ({len(pts)} points, {mv.mean():.1%} moving)")
    if args.ply:
        common.log(f"wrote {ply.write_ply(args.ply, pts, cols)}")
    return out


if __name__ == "__main__":
    main()
