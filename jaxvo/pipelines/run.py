"""Run sequences through the tracker: the library side of ``jaxvo run``.

One sequence: :func:`run_sequence` tracks a :class:`jaxvo.data.TumSequence` with
:func:`jaxvo.tracking.odometry.track`, writes the trajectory as it goes and returns a
:class:`RunResult`; :func:`run_sequences` does so for several sequences of one image size as
one batch. Folders, as ``jaxvo run`` takes them, in three steps:

* :func:`jaxvo.pipelines.settings.setup_run`: the config, keyframe policy, seed and reader options
  of a run, from options and a config file, which may be a trajectory written by an earlier run
  (its ``#`` header reruns it);
* :func:`plan_run`: the sequence folders opened (a folder of sequence folders stands for them,
  :func:`expand_sequences`), their first frames and ground truth read, the outputs checked,
  the sequences grouped into batches by image size;
* :func:`execute_run`: the tracking, each trajectory written under its ``.partial`` name and
  renamed when complete, the errors against ground truth; a :class:`RunReport`.

Bad input raises :class:`jaxvo.data.DatasetError` / ``ValueError`` with a one-line message naming
the file.
"""
from __future__ import annotations

import dataclasses
import functools
import time
from pathlib import Path
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np

from jaxvo.data.outputs import check_output, check_output_folder, finish, partial_path, write_text
from jaxvo.data import DatasetError, TumSequence, find_sequences, open_sequence
from jaxvo.evaluation.scoring import TrajectoryErrors, trajectory_errors
from jaxvo.frame import has_depth
from jaxvo.pipelines.mapping import moving_mask
from jaxvo.pipelines.messages import one_line
from jaxvo.pipelines.sequences import check_camera_size
from jaxvo.pipelines.settings import RunSetup, run_header

__all__ = ["RunResult", "run_sequence", "run_sequences", "stamp_name", "RunPlan", "SequenceRun", "RunReport",
           "expand_sequences", "plan_run", "execute_run", "count_poses", "mask_name", "MASK_INDEX",
           "unusable_message"]


def stamp_name(t: float) -> str:
    return f"{float(t):.6f}"


#: the index of the outlier masks of ``jaxvo run --save-masks`` (in their folder)
MASK_INDEX = "masks.txt"
MASK_INDEX_HEADER = ("# outlier masks of jaxvo run --save-masks, one per pair; a mask lies on the reference "
                     "frame's pixels\n# reference_timestamp file current_timestamp\n")


def mask_name(ref_stamp: float, cur_stamp: float) -> str:
    """The file of one pair's outlier mask: named by the reference and the current frame
    (``<reference>-<current>.png``), so the pairs that share a keyframe keep one file each."""
    return f"{stamp_name(ref_stamp)}-{stamp_name(cur_stamp)}.png"


@dataclasses.dataclass(frozen=True)
class RunResult:
    """What :func:`run_sequence` did.

    stamps (n,) s and poses (n, 4, 4) T_world_cam of the frames written (frame 0 at the start pose);
    inlier_ratio, valid (n-1,) per finished pair; compile_s: wall time until the first pair was
    done (reading, compiling and running it); fps: pairs per second after the first pair (NaN
    with fewer than 2 pairs); interrupted: ended by Ctrl-C; error: the one-line reason a
    sequence of a batch stopped early (a frame that does not read), None when it did not.
    without_depth: how many of the failed pairs' current frames had no depth (a covered sensor:
    held without an estimate).
    """
    method: str
    stamps: np.ndarray
    poses: np.ndarray
    inlier_ratio: np.ndarray
    valid: np.ndarray
    compile_s: float
    fps: float
    wall_s: float
    interrupted: bool = False
    error: Optional[str] = None
    without_depth: int = 0

    @property
    def pairs(self) -> int:
        return int(self.inlier_ratio.size)

    @property
    def failures(self) -> int:
        return int(np.sum(~self.valid))

    @property
    def unusable(self) -> bool:
        """The run produced nothing usable: more than half of its pairs failed (their pose is the
        previous one held), as when the depth scale is wrong or masks hide every pixel."""
        return self.pairs > 0 and 2 * self.failures > self.pairs


class _Recorder:
    """What a run keeps of one sequence: the trajectory written as it grows (after the ``#``
    header of :func:`jaxvo.pipelines.settings.run_header`), optional outlier masks, poses, inlier ratios and timings.
    ``step(TrackStep)`` records one frame; ``result(interrupted)`` gives the RunResult. A line is
    written once the step says it is final (``TrackStep.settled``: with ``TrackConfig.poses``
    "refined" a few frames later, from ``TrackStep.refined``; with "tracked" at once), the frames still open
    at :meth:`close` as they stand then (the end of the run, or Ctrl-C)."""

    def __init__(self, seq: TumSequence, config, seed: int, out=None, save_masks=None,
                 on_pair: Optional[Callable] = None, pbar=None, policy=None):
        from jaxvo.config import TrackConfig
        from jaxvo.data.trajectory import HEADER, TrajectoryWriter

        self.seq, self.method, self.on_pair, self.pbar = seq, config.method, on_pair, pbar
        self.stamps = np.asarray(seq.timestamps, np.float64)
        self.mask_dir, self.mask_index, self.error = None, [], None
        self.without_depth = 0
        if save_masks is not None:
            self.mask_dir = Path(save_masks)
            try:
                self.mask_dir.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise DatasetError(f"{self.mask_dir}: cannot create mask folder ({e.strerror or e})") from None
        header = "\n".join(run_header(config, policy if policy is not None else TrackConfig(), seed, seq) + [HEADER])
        self.writer = TrajectoryWriter(out, header=header) if out is not None else None
        self.open_poses: dict = {}    # frame -> pose, the frames not settled yet
        self.poses = [np.eye(4)]
        self.ratios: List[float] = []
        self.valids: List[bool] = []
        self.times: List[float] = []
        self.t0 = time.perf_counter()

    def open(self) -> None:
        if self.writer is not None:
            self.writer.open()
            self.writer.write_first(self.stamps[0])

    def close(self) -> None:
        for i in sorted(self.open_poses):
            self._line(i, self.open_poses[i])
        self.open_poses = {}
        if self.writer is not None:
            self.writer.close()
        if self.mask_dir is not None:
            write_text(self.mask_dir / MASK_INDEX, MASK_INDEX_HEADER + "".join(self.mask_index))

    def frames(self, frames):
        """``frames`` until one does not read: then the error is kept (``self.error``) and the
        sequence ends there, so the other sequences of its batch go on."""
        try:
            yield from frames
        except (DatasetError, ValueError, OSError) as e:
            self.error = one_line(e)

    def step(self, step) -> None:
        import cv2

        i, est, pose, ref = step.frame - 1, step.estimate, step.T_world_cur, step.reference
        # no estimate: the frame has no depth, and was held
        self.ratios.append(0.0 if est is None else float(est.inlier_ratio))
        self.without_depth += est is None
        self.valids.append(bool(step.valid))
        # the frames this step settles, in order; the others wait
        self.open_poses.update({step.frame: pose} if step.refined is None else step.refined)
        for k in range(len(self.poses), step.settled):
            self._line(k, self.open_poses.pop(k))
        if self.mask_dir is not None and est is not None:
            m = moving_mask(est, self.seq.camera.width, self.seq.camera.height, step.static_mask)
            name = mask_name(self.stamps[ref], self.stamps[i + 1])
            p = self.mask_dir / name
            if not cv2.imwrite(str(p), m.astype(np.uint8) * 255):
                raise DatasetError(f"{p}: cannot write the mask image (disk full or no permission?)")
            self.mask_index.append(f"{stamp_name(self.stamps[ref])} {name} {stamp_name(self.stamps[i + 1])}\n")
        if self.on_pair is not None:
            self.on_pair(step)
        self.times.append(time.perf_counter())
        if self.pbar is not None:
            fps = self.fps()
            self.pbar.set_postfix(inliers=f"{self.ratios[-1]:.2f}", refresh=False,
                                  **({"fps": f"{fps:.2f}"} if np.isfinite(fps) else {}))
            self.pbar.update(1)

    def _line(self, k: int, pose) -> None:
        """Frame k's pose, the next one in order: kept, and written to the trajectory."""
        self.poses.append(np.asarray(pose, np.float64))
        if self.writer is not None:
            self.writer.write(self.stamps[k], pose, held=not self.valids[k - 1])

    def fps(self) -> float:
        """Pairs per second after the first pair (compilation): the summary's frames/s."""
        times = self.times
        return (len(times) - 1) / (times[-1] - times[0]) if len(times) >= 2 and times[-1] > times[0] \
            else float("nan")

    def result(self, interrupted: bool) -> "RunResult":
        times, n = self.times, len(self.poses)
        compile_s = (times[0] - self.t0) if times else float("nan")
        fps = self.fps()
        return RunResult(self.method, self.stamps[:n].copy(), np.stack(self.poses), np.asarray(self.ratios),
                         np.asarray(self.valids, bool), compile_s, fps, time.perf_counter() - self.t0, interrupted,
                         self.error, self.without_depth)


def run_sequence(seq: TumSequence, config, seed: int = 0, out=None, save_masks=None,
                 on_pair: Optional[Callable] = None, pbar=None, policy=None) -> RunResult:
    """Track ``seq`` with :func:`jaxvo.tracking.odometry.track` and ``policy`` (a
    :class:`jaxvo.config.TrackConfig`; default the library's TrackConfig()) and the key
    ``jax.random.key(seed)``, so results equal the library's. The trajectory goes to ``out`` as
    it grows (first frame at identity), after the ``#`` header of :func:`jaxvo.pipelines.settings.run_header` (version,
    method, seed, config, policy, reader settings). Optionally each estimate's outlier mask goes
    into ``save_masks``: one PNG per pair named by the reference and the current frame
    (:func:`mask_name`; the mask lives on the reference image's pixels), listed in its index
    ``MASK_INDEX`` (``reference_timestamp file current_timestamp`` per line). ``on_pair(step)`` is called with each
    :class:`jaxvo.tracking.odometry.TrackStep`; ``pbar`` (tqdm) is advanced once per frame. Ctrl-C ends the
    run early (``interrupted=True``) keeping everything written so far.
    """
    import jax

    from jaxvo.tracking.odometry import track

    rec = _Recorder(seq, config, seed, out, save_masks, on_pair, pbar, policy)
    interrupted = False
    frames_it = seq.prefetch(2)
    frames = (f for _, f in frames_it)
    try:
        rec.open()
        track(frames, seq.camera, config, jax.random.key(int(seed)), callback=rec.step, policy=policy)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        frames.close()
        frames_it.close()
        rec.close()
    return rec.result(interrupted)


def run_sequences(seqs: List[TumSequence], config, seed: int = 0, outs=None, on_pair: Optional[Callable] = None,
                  pbar=None, policy=None) -> List[RunResult]:
    """:func:`run_sequence` for several sequences of one image size as one batch
    (:func:`jaxvo.tracking.batch.track_batch`: their estimates vmapped together, in lockstep, over the
    available devices). Each sequence uses the key ``jax.random.key(seed)`` as it would alone and
    writes its trajectory to its entry of ``outs`` (None = none). ``on_pair(s, step)`` is called
    with sequence index and :class:`jaxvo.tracking.odometry.TrackStep`. A frame that does not read
    ends its sequence there (its RunResult's ``error``); the others go on. Returns one RunResult
    per sequence.
    """
    import functools

    import jax

    from jaxvo.tracking.batch import track_batch

    outs = [None] * len(seqs) if outs is None else list(outs)
    recs = [_Recorder(seq, config, seed, out, None, None if on_pair is None else functools.partial(on_pair, s),
                      pbar, policy) for s, (seq, out) in enumerate(zip(seqs, outs))]
    interrupted = False
    iters = [seq.prefetch(2) for seq in seqs]
    frames = [rec.frames(f for _, f in it) for rec, it in zip(recs, iters)]
    try:
        for rec in recs:
            rec.open()
        track_batch(frames, [seq.camera for seq in seqs], config, [jax.random.key(int(seed))] * len(seqs),
                    policy, callbacks=[rec.step for rec in recs])
    except KeyboardInterrupt:
        interrupted = True
    finally:
        for f, it in zip(frames, iters):
            f.close()
            it.close()
        for rec in recs:
            rec.close()
    return [rec.result(interrupted) for rec in recs]


# ----------------------------------------------------------------------------- folders, as jaxvo run takes them

def expand_sequences(paths) -> List[Path]:
    """The sequence folders ``paths`` name: each path as it is, except a folder that is not a
    sequence itself but holds sequence folders (rgb.txt + depth.txt), which stands for them."""
    dirs = []
    for p in map(Path, paths):
        inner = find_sequences(p) if p.is_dir() else []
        if inner == [p]:
            inner = []              # a TUM-layout sequence folder itself
        if inner:
            try:
                open_sequence(p, max_frames=1)
                inner = []          # a sequence of another layout (ICL-NUIM, Redwood): itself
            except (DatasetError, ValueError):
                pass
        dirs += inner or [p]
    return dirs



@dataclasses.dataclass(frozen=True)
class RunPlan:
    """A run ready to go (:func:`plan_run`): its setup, the sequences (opened, first frame and
    ground truth read), each one's trajectory file, the outlier-mask folder (one sequence only)
    and the batches: indices of the sequences of one image size, tracked together."""
    setup: RunSetup
    sequences: Tuple[TumSequence, ...]
    outputs: Tuple[Path, ...]
    batches: Tuple[Tuple[int, ...], ...]
    save_masks: Optional[Path] = None


def plan_run(sequence_dirs: Sequence, setup: RunSetup, out=None, out_dir=".", save_masks=None,
             config_file=None, force: bool = False) -> RunPlan:
    """Open the sequence folders and check the outputs before anything is tracked.

    One folder: its trajectory goes to ``out`` (default traj.txt), its outlier masks to
    ``save_masks``. Several: each trajectory to ``out_dir/<sequence name>.txt`` (``-k`` appended
    to names that repeat), created here. Outputs that would replace or land inside an input
    (the folders, ``config_file``, the user masks) raise DatasetError unless ``force``; so do a
    sequence of fewer than 2 frames, a first frame that does not read and ground truth that does
    not cover the frames.
    """
    dirs = [Path(d) for d in sequence_dirs]
    if len(dirs) == 1:
        out = Path("traj.txt") if out is None else Path(out)
        inputs = [dirs[0], config_file, setup.reader.mask_dir]
        check_output(out, inputs, force, "--out")
        if save_masks is not None:
            check_output_folder(save_masks, inputs, force, "--save-masks")
        seq = setup.reader.open(dirs[0])
        if len(seq) < 2:
            raise DatasetError(f"{dirs[0]}: only {len(seq)} frame(s) to use, need at least 2")
        check_camera_size(seq)
        _check_first_frame(seq)      # a bad first image is reported before compiling
        seq.groundtruth              # and so is ground truth that does not cover the frames
        return RunPlan(setup, (seq,), (out,), ((0,),), None if save_masks is None else Path(save_masks))
    seqs = [setup.reader.open(d) for d in dirs]
    names = [seq.name for seq in seqs]
    out_dir = Path(out_dir)
    outs = [out_dir / (f"{n}.txt" if names.count(n) == 1 else f"{n}-{k}.txt") for k, n in enumerate(names)]
    for seq, o in zip(seqs, outs):
        if len(seq) < 2:
            raise DatasetError(f"{seq.path}: only {len(seq)} frame(s) to use, need at least 2")
        check_output(o, [s.path for s in seqs] + [config_file], force, "--out-dir")
        check_camera_size(seq)
        _check_first_frame(seq)
    groups: dict = {}
    for k, seq in enumerate(seqs):
        groups.setdefault((seq.camera.width, seq.camera.height), []).append(k)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise DatasetError(f"--out-dir {out_dir}: cannot create it ({e.strerror or e})") from None
    return RunPlan(setup, tuple(seqs), tuple(outs), tuple(tuple(g) for g in groups.values()))


@dataclasses.dataclass(frozen=True)
class SequenceRun:
    """One sequence of a :class:`RunReport`: the sequence, its :class:`RunResult` (None: its
    batch was not reached before Ctrl-C), where its trajectory is (under its ``.partial`` name
    unless it ran to the end), its errors against the sequence's ground truth (None without
    ground truth) and why it is not a success (None when it is): a frame that did not read, or
    :func:`unusable_message`."""
    sequence: TumSequence
    result: Optional[RunResult]
    trajectory: Path
    errors: Optional[TrajectoryErrors]
    problem: Optional[str] = None


@dataclasses.dataclass(frozen=True)
class RunReport:
    """What :func:`execute_run` did: one :class:`SequenceRun` per sequence of the plan (in its
    order) and whether Ctrl-C ended it."""
    runs: Tuple[SequenceRun, ...]
    interrupted: bool

    @property
    def problems(self) -> Tuple[str, ...]:
        """The one-line reasons, per sequence that is not a success."""
        return tuple(r.problem for r in self.runs if r.problem is not None)


def count_poses(path) -> int:
    """The number of pose lines in a trajectory file (0 when it cannot be read)."""
    try:
        return sum(1 for ln in Path(path).read_text().splitlines() if ln.strip() and not ln.startswith("#"))
    except OSError:
        return 0


def _check_first_frame(seq: TumSequence) -> None:
    """Read the sequence's first frame (DatasetError naming the file where it does not read), which
    the odometry starts from and so must have depth, where later frames without depth are held."""
    if not has_depth(seq.frame(0), str(seq.depth_paths[0])):
        raise DatasetError(f"{seq.depth_paths[0]}: depth has no valid pixel (all zero, negative or NaN), and the "
                           f"first frame must have depth: the odometry starts from it (--start N begins later)")


def unusable_message(seq: TumSequence, res: RunResult, trajectory) -> Optional[str]:
    """The one-line error of a run that produced nothing usable (:attr:`RunResult.unusable`:
    more than half of the pairs failed), naming the likely cause from the first frame: masks that
    hide (nearly) every pixel, or a depth whose median is implausible at the scale used; else
    every usual cause. None for a usable run."""
    if not res.unusable:
        return None
    from jaxvo.data import read_frame_mask

    cause = None
    try:
        _, depth = seq.read_images(0)
        valid = depth[depth > 0]
        median = float(np.median(valid)) / seq.depth_scale if valid.size else float("nan")
        mp = seq.mask_paths[0] if getattr(seq, "mask_paths", None) else None
        used = float((read_frame_mask(mp, depth.shape) > 0).mean()) if mp is not None else 1.0
    except (DatasetError, ValueError, OSError):
        median, used = float("nan"), 1.0
    if 2 * res.without_depth > res.pairs:
        cause = (f"{res.without_depth} of the frames have no depth (every depth pixel zero: the sensor "
                 f"covered or too close, or depth images that do not belong to the recording)")
    elif used < 0.05:
        cause = (f"the masks of {seq.mask_dir} leave {100 * used:.1f} % of the pixels (nonzero = use the pixel; "
                 f"a 16-bit 0/1 mask reads as all 0: write 8-bit 0/255)")
    elif not valid.size:
        cause = "the first frame has no valid depth"
    else:
        cause = (f"a wrong --depth-scale? ({seq.depth_scale:g} makes the first frame's median depth "
                 f"{median:.2f} m; TUM/Bonn/ETH3D/ICL-NUIM use 5000, Redwood/Open3D/RealSense millimetres 1000), "
                 f"masks that hide the scene, or images without texture")
    return (f"{seq.path}: nothing usable: {res.failures} of {res.pairs} pairs failed (more than half); likely "
            f"cause: {cause}; the trajectory is kept in {trajectory}")


def _sequence_run(seq: TumSequence, res: RunResult, out: Path, max_dt: float) -> SequenceRun:
    """A :class:`SequenceRun` of a finished (or stopped) tracking: the trajectory is renamed to
    ``out`` when the sequence ran to its end (a run with nothing usable too: it is complete)."""
    partial = partial_path(out)
    done = not res.interrupted and res.error is None
    if done:
        finish(partial, out)
    trajectory = out if done else partial
    gt = seq.groundtruth
    errors = trajectory_errors(gt, res.stamps, res.poses, max_dt) if gt is not None and len(res.stamps) else None
    problem = None
    if res.error is not None:
        n = count_poses(partial)
        problem = res.error + (f" ({n} finished poses kept in {partial})" if n else "")
    elif not res.interrupted:
        problem = unusable_message(seq, res, trajectory)
    return SequenceRun(seq, res, trajectory, errors, problem)


def execute_run(plan: RunPlan, pbar=None, on_pair: Optional[Callable] = None) -> RunReport:
    """Track the plan's sequences: one alone with :func:`run_sequence`, several batch by batch with
    :func:`run_sequences`. Each trajectory grows under its ``.partial`` name (flushed line by line)
    and gets its name when its sequence is done (a finished batch's at once). ``on_pair(k, step)``
    is called with the sequence's index in the plan and each
    :class:`jaxvo.tracking.odometry.TrackStep`; ``pbar`` (tqdm) advances once per frame.

    One sequence: a failure raises DatasetError saying where the finished poses are kept.
    Several: a frame that does not read stops only its sequence, a failing batch only its
    sequences; each one's reason is its SequenceRun's ``problem``, as is a run with nothing
    usable (:func:`unusable_message`).
    """
    s = plan.setup
    if len(plan.sequences) == 1:
        seq, out = plan.sequences[0], plan.outputs[0]
        partial = partial_path(out)
        masks = None if plan.save_masks is None else partial_path(plan.save_masks, fresh=True)
        try:
            res = run_sequence(seq, s.config, s.seed, out=partial, save_masks=masks, pbar=pbar,
                               policy=s.policy, on_pair=None if on_pair is None else functools.partial(on_pair, 0))
        except (DatasetError, ValueError, OSError) as e:
            n = count_poses(partial)
            raise DatasetError(one_line(e) + (f" ({n} finished poses kept in {partial})" if n else "")) from None
        if masks is not None and not res.interrupted:
            finish(masks, plan.save_masks)
        return RunReport((_sequence_run(seq, res, out, s.reader.max_dt),), res.interrupted)
    runs: dict = {}
    interrupted = False
    for ks in plan.batches:
        if interrupted:
            break
        seqs = [plan.sequences[k] for k in ks]
        try:
            res = run_sequences(seqs, s.config, s.seed, [partial_path(plan.outputs[k]) for k in ks], pbar=pbar,
                                policy=s.policy,
                                on_pair=None if on_pair is None else (lambda j, step, ks=ks: on_pair(ks[j], step)))
        except (DatasetError, ValueError, OSError) as e:
            for k in ks:
                partial = partial_path(plan.outputs[k])
                n = count_poses(partial)
                runs[k] = SequenceRun(plan.sequences[k], None, partial, None,
                                      one_line(e) + (f" ({n} finished poses kept in {partial})" if n else ""))
            continue
        for k, seq, r in zip(ks, seqs, res):
            runs[k] = _sequence_run(seq, r, plan.outputs[k], seq.max_dt)
        interrupted = any(r.interrupted for r in res)
    out = [runs.get(k) or SequenceRun(seq, None, partial_path(plan.outputs[k]), None)
           for k, seq in enumerate(plan.sequences)]
    return RunReport(tuple(out), interrupted)
