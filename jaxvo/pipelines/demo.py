"""The work of ``jaxvo demo``: a synthetic dynamic scene, the three estimators, one table and figures."""
from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from pathlib import Path
from typing import Callable, Dict, Optional

import numpy as np

from jaxvo.camera import DEFAULT, camera_for_size
from jaxvo.data import DatasetError, TumSequence
from jaxvo.data.outputs import check_own_folder, finish, partial_path, write_text, writing
from jaxvo.evaluation.scoring import load_mask, true_masks
from jaxvo.pipelines.mapping import moving_mask
from jaxvo.evaluation.metrics import ATEResult, RPEResult
from jaxvo.pipelines.run import RunResult, run_sequence

__all__ = ["run_demo", "DemoResult", "DemoMethod", "DEMO_METHODS", "parse_size", "fmt", "progress_bar"]
DEMO_METHODS = ("classic", "huber", "ransac")


@dataclasses.dataclass(frozen=True)
class DemoMethod:
    """One estimator's numbers in the demo.

    rpe: RPE over 1 frame (m/frame, deg/frame); ate: ATE after rigid alignment (m); run: the
    :class:`jaxvo.pipelines.run.RunResult`; precision, recall, iou: its moving mask against the
    true moving pixels, pooled over the reference frames (NaN where undefined).
    """
    rpe: RPEResult
    ate: ATEResult
    run: RunResult
    precision: float
    recall: float
    iou: float


@dataclasses.dataclass(frozen=True)
class DemoResult:
    """What :func:`run_demo` made: ``table`` (the printed text), ``results`` (per method),
    ``figures`` (name -> PNG path), ``wall_s`` (s) and ``overlay_frame`` (the frame index of
    inliers_outliers.png)."""
    table: str
    results: Dict[str, DemoMethod]
    figures: Dict[str, Path]
    wall_s: float
    overlay_frame: Optional[int]


def parse_size(size) -> tuple:
    """``"WIDTHxHEIGHT"`` (or a (width, height) pair) -> (width, height) ints; ValueError naming the
    problem for anything else or a side under 32 pixels."""
    if isinstance(size, str):
        parts = size.lower().split("x")
        try:
            if len(parts) != 2:
                raise ValueError
            w, h = int(parts[0]), int(parts[1])
        except ValueError:
            raise ValueError(f"--size {size!r}: expected WIDTHxHEIGHT, e.g. 424x240") from None
    else:
        w, h = (int(v) for v in size)
    if w < 32 or h < 32:
        raise ValueError(f"--size {w}x{h}: width and height must be at least 32 pixels")
    return w, h


def fmt(x, nd=4) -> str:
    """``x`` with ``nd`` decimals; "-" for None, NaN and inf."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-"
    return f"{x:.{nd}f}"


def progress_bar(**kw):
    """A tqdm progress bar on stderr. Its rate is not tqdm's (which counts the compilation of
    the first step): a run's recorder shows its own ``fps`` after compilation, the number of
    the run's summary."""
    from tqdm import tqdm

    kw.setdefault("bar_format", "{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}<{remaining}{postfix}]")
    return tqdm(dynamic_ncols=True, file=sys.stderr, **kw)



def _sequence_matches(seq_dir: Path, name, frames, seed, cam, sensor) -> bool:
    try:
        info = json.loads((seq_dir / "info.json").read_text())
    except (OSError, ValueError):
        return False
    c = info.get("camera") or {}
    return (info.get("name") == name and info.get("frames") == frames and info.get("seed") == seed
            and c.get("width") == cam.width and c.get("height") == cam.height
            and (info.get("sensor") is not None) == bool(sensor)
            and (seq_dir / "groundtruth.txt").is_file() and (seq_dir / "masks.txt").is_file())


def _written_by_jaxvo(seq_dir: Path) -> bool:
    """A synthetic sequence folder jaxvo wrote (its info.json names the scene, seed and frames)."""
    try:
        info = json.loads((seq_dir / "info.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(info, dict) and {"name", "seed", "frames", "camera"} <= set(info)


def run_demo(out_dir, frames: int = 100, seed: int = 0, seq_name: str = "seq2", size: str = "320x240",
             sensor: bool = True, progress: bool = True, methods=DEMO_METHODS, force: bool = False,
             check: Callable[[], None] = lambda: None, on_start: Callable[[], None] = lambda: None) -> DemoResult:
    """The work of ``jaxvo demo``: the sequence (reused under ``out_dir/sequence`` when it matches,
    replaced when jaxvo wrote it; a folder of other files there is refused unless ``force``),
    each method's run, table and figures, written into ``out_dir``; returns a :class:`DemoResult`.
    Every file is written under its ``.partial`` name and renamed when complete, so an
    interrupted demo leaves the previous complete files as they were. ``check()`` is called
    between steps (it raises KeyboardInterrupt to stop), ``on_start()`` once the outputs are checked."""
    from jaxvo import viz
    from jaxvo.evaluation.metrics import ate, mask_scores, rpe
    from jaxvo.config import Config
    from jaxvo.synthetic import SensorModel, generate

    t_start = time.perf_counter()
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise DatasetError(f"{out}: cannot create output folder ({e.strerror or e})") from None
    width, height = parse_size(size)
    size = f"{width}x{height}"
    cam = camera_for_size(DEFAULT, width, height)
    seq_dir = out / "sequence"
    reuse = _sequence_matches(seq_dir, seq_name, frames, seed, cam, sensor)
    if not reuse:
        check_own_folder(seq_dir, _written_by_jaxvo, force)
    on_start()
    total = (0 if reuse else frames) + len(methods) * (frames - 1)
    pbar = progress_bar(total=total, unit="step", desc="demo") if progress else None
    try:
        if not reuse:
            if pbar is not None:
                pbar.set_description(f"demo: render {seq_name}")
            done = [0]

            def prog(k, n):
                check()
                if pbar is not None:
                    pbar.update(k - done[0])
                done[0] = k
            tmp = partial_path(seq_dir, fresh=True)
            generate(seq_name, tmp, frames=frames, seed=seed, camera=cam,
                     sensor=SensorModel() if sensor else None, progress=prog)
            finish(tmp, seq_dir)
        seq = TumSequence(seq_dir, camera=cam)
        gt_t, gt_T = seq.groundtruth
        mt, mpaths = true_masks(seq_dir)
        masks_true = [load_mask(p) for p in mpaths]
        cover = np.array([m.mean() for m in masks_true])
        # inlier and defined masks of each method's estimates (the segmentation's dynamic pixels
        # counted as outliers), by reference frame (the last, longest-baseline one)
        seen = {}
        results = {}
        for method in methods:
            config = Config(method=method)
            counts = np.zeros(4, np.int64)

            def on_pair(step, counts=counts, method=method):
                est = step.estimate
                pred, val = moving_mask(est, cam.width, cam.height, step.static_mask, valid_too=True)
                s = mask_scores(pred, masks_true[step.reference], val)
                counts += (s.tp, s.fp, s.fn, s.tn)
                seen.setdefault(method, {})[step.reference] = (~pred, val)
                check()
            if pbar is not None:
                pbar.set_description(f"demo: {method}")
            traj = out / f"traj_{method}.txt"
            res = run_sequence(seq, config, seed, out=partial_path(traj), on_pair=on_pair, pbar=pbar)
            if res.interrupted:
                raise KeyboardInterrupt
            finish(partial_path(traj), traj)
            r1 = rpe(gt_t, gt_T, res.stamps, res.poses, 1, "f")
            a = ate(gt_t, gt_T, res.stamps, res.poses)
            tp, fp, fn, tn = (int(x) for x in counts)
            results[method] = DemoMethod(
                rpe=r1, ate=a, run=res,
                precision=tp / (tp + fp) if tp + fp else float("nan"),
                recall=tp / (tp + fn) if tp + fn else float("nan"),
                iou=tp / (tp + fp + fn) if tp + fp + fn else float("nan"),
            )
    finally:
        if pbar is not None:
            pbar.close()

    # table
    head = (f"{'method':<9}{'RPE trans':>11}{'RPE rot':>10}{'ATE':>9}{'FPS':>7}{'inliers':>9}"
            f"{'mask prec':>11}{'mask rec':>10}")
    units = f"{'':<9}{'mm/frame':>11}{'deg/frame':>10}{'mm':>9}{'':>7}{'ratio':>9}{'':>11}{'':>10}"
    rows = [f"{seq_name} ({frames} frames, {size}{', sensor noise' if sensor else ''}, seed {seed}); "
            f"moving pixels per frame: {100 * cover.mean():.1f} % mean, {100 * cover.max():.1f} % max",
            head, units]
    for m, d in results.items():
        rows.append(f"{m:<9}{1000 * d.rpe.trans_stats.rmse:>11.2f}{d.rpe.rot_stats.rmse:>10.3f}"
                    f"{1000 * d.ate.rmse:>9.1f}{fmt(d.run.fps, 1):>7}"
                    f"{float(np.mean(d.run.inlier_ratio)):>9.3f}{fmt(d.precision, 3):>11}"
                    f"{fmt(d.recall, 3):>10}")
    table = "\n".join(rows)

    # figures
    figs = {}
    t0 = seq.timestamps[0]
    keep = (gt_t >= seq.timestamps[0] - 0.05) & (gt_t <= seq.timestamps[-1] + 0.05)
    trajs = {"groundtruth": gt_T[keep, :3, 3]}
    trajs.update({m: d.ate.aligned[:, :3, 3] for m, d in results.items()})
    figs["trajectories"] = _save_figure(
        viz.plot_trajectories(trajs, title=f"{seq_name}: trajectories, top view (aligned to ground truth)"),
        out / "trajectories.png")
    figs["translational_error"] = _save_figure(
        viz.plot_errors_over_time({m: d.rpe.stamps_j - t0 for m, d in results.items()},
                                  {m: 1000 * d.rpe.trans for m, d in results.items()},
                                  ylabel="translational RPE [mm/frame]",
                                  title=f"{seq_name}: translational error per frame"),
        out / "translational_error.png")
    # the dynamic frame shown in the overlay: the reference frame (one that every method estimated
    # against; with keyframes not every frame is one) with the most moving pixels
    common = set.intersection(*(set(v) for v in seen.values())) if seen else set()
    show = max(common, key=lambda i: (cover[i], -i)) if common else 0
    shown = {m: v[show] for m, v in seen.items() if show in v}
    if shown:
        import matplotlib.pyplot as plt
        fr = seq.frame(show)
        fig, axs = plt.subplots(1, len(shown), figsize=(4.2 * len(shown), 3.6))
        axs = np.atleast_1d(axs)
        for ax, (m, (inl, val)) in zip(axs, shown.items()):
            ax.imshow(viz.outlier_overlay(fr.intensity, inl, val))
            tm = masks_true[show]
            if tm.any():
                ax.contour(tm.astype(float), levels=[0.5], colors="red", linewidths=0.7)
            ax.set_title(f"{m}: inliers blue, outliers green", fontsize=9)
            ax.set_axis_off()
        fig.suptitle(f"{seq_name} frame {show} (t = {seq.timestamps[show] - t0:.2f} s); true moving pixels "
                     f"outlined red", fontsize=9)
        fig.tight_layout()
        check()
        figs["inliers_outliers"] = _save_figure(fig, out / "inliers_outliers.png")

    wall = time.perf_counter() - t_start
    js = {"sequence": seq_name, "frames": frames, "size": size, "sensor": sensor, "seed": seed,
          "overlay_frame": show, "wall_s": wall, "methods": {}}
    for m, d in results.items():
        js["methods"][m] = {"rpe_1f": d.rpe.to_dict(), "ate": d.ate.to_dict(),
                            "fps": _clean(d.run.fps), "compile_s": _clean(d.run.compile_s),
                            "inlier_ratio_mean": float(np.mean(d.run.inlier_ratio)),
                            "failures": d.run.failures,
                            "mask_precision": _clean(d.precision), "mask_recall": _clean(d.recall),
                            "mask_iou": _clean(d.iou)}
    check()
    write_text(out / "results.json", json.dumps(js, indent=1) + "\n")
    write_text(out / "results.md", "```\n" + table + "\n```\n")
    return DemoResult(table, results, figs, wall, show)


def _save_figure(fig, path) -> Path:
    """:func:`jaxvo.viz.save_figure` under the ``.partial`` name, renamed when complete."""
    from jaxvo import viz

    return writing(path, lambda p: viz.save_figure(fig, p))


def _clean(x):
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else x

