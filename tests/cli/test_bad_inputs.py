"""The catalogue of bad and hostile inputs: every one gets one clear line and loses nothing.

Each CLI case is (arguments built in a fresh copy of a tiny synthetic sequence, expected exit
code, a fragment of the message): it must end with exactly one ``error:`` line on stderr that
contains the fragment, no traceback, and every file in the case's folder untouched (nothing
written, nothing changed). Each library case must raise ValueError whose one-line message
contains the fragment. Almost all fail before any JAX compilation; the tests at the end run
the estimator (a failure half way keeps the finished poses) and the command as a process
(native libpng warnings, Ctrl-C while starting and while compiling).
"""
from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest
from click.testing import CliRunner

from jaxvo import Camera, Config, Frame, TrackConfig, estimate_motion, track
from jaxvo.camera import DEFAULT
from jaxvo.cli.main import main
from jaxvo.data.tum import TumSequence
from jaxvo.data.trajectory import read_tum_trajectory
from jaxvo.validation import check_fields, real

REPO = Path(__file__).resolve().parents[2]
CAM = DEFAULT.at_level(2)          # 160x120


@pytest.fixture(scope="module")
def base_seq(tmp_path_factory):
    """A 5-frame 160x120 synthetic sequence (seq1: fixed camera, a person walking), made once."""
    from jaxvo.synthetic import generate
    return generate("seq1", tmp_path_factory.mktemp("base") / "seq", frames=5, seed=1, camera=CAM)


class Case:
    """A fresh folder ``root`` holding a copy of the base sequence ``seq`` and helpers to add files."""

    def __init__(self, root: Path, base: Path):
        self.root = root
        self.seq = root / "seq"
        shutil.copytree(base, self.seq)
        self.gt = self.seq / "groundtruth.txt"
        self.est = root / "est.txt"
        shutil.copyfile(self.gt, self.est)      # a perfect estimate

    def write(self, name: str, text, binary: bool = False) -> Path:
        p = self.root / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(text) if binary else p.write_text(text)
        return p

    def edit(self, rel: str, fn) -> Path:
        """Replace the text of ``seq/rel`` by ``fn(text)``."""
        p = self.seq / rel
        p.write_text(fn(p.read_text()))
        return self.seq

    def first(self, listing: str) -> Path:
        for ln in (self.seq / listing).read_text().splitlines():
            if ln and not ln.startswith("#"):
                return self.seq / ln.split()[1]
        raise AssertionError(listing)


def _snapshot(root: Path) -> dict:
    return {str(p.relative_to(root)): hashlib.sha1(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def _cfg(c: Case, text: str):
    return ["run", c.seq, "--config", c.write("cfg.json", text), "--out", c.root / "t.txt"]


def _truncate(p: Path) -> None:
    p.write_bytes(p.read_bytes()[:60])


def _depth8(c: Case):
    import cv2
    p = c.first("depth.txt")
    cv2.imwrite(str(p), np.zeros((120, 160), np.uint8))
    return ["run", c.seq, "--out", c.root / "t.txt"]


def _gt_short(c: Case):
    lines = c.gt.read_text().splitlines()
    c.gt.write_text("\n".join(lines[:3]) + "\n")   # 2 comment lines + the first pose only
    return c.seq


def _masked_gt_file(c: Case):
    return ["eval", c.gt, c.est, "--delta-unit", "f", "--masks-dir", c.root]


def _size_640(text: str) -> str:
    return text.replace('"width": 160', '"width": 640').replace('"height": 120', '"height": 480')


def _copy(c: Case, name: str) -> Path:
    shutil.copytree(c.seq, c.root / name)
    return c.root / name


def _header(c: Case, sequence: str, seed: str = "0"):
    """``jaxvo run --config`` of a trajectory whose header has the ``# sequence:`` entry given."""
    h = c.write("h.txt", f"# config: {{}}\n# seed: {seed}\n# sequence: {sequence}\n0.0 0 0 0 0 0 0 1\n")
    return ["run", c.seq, "--config", h, "--out", c.root / "t.txt"]


_MOVED_EST = "\n".join(f"{100 + i:.6f} 0 0 0 0 0 0 1" for i in range(5)) + "\n"

CLI_CASES = [
    # --- run: folders and files
    ("run-missing-folder", lambda c: ["run", c.root / "nope", "--out", c.root / "t.txt"], "does not exist"),
    ("run-folder-is-file", lambda c: ["run", c.est, "--out", c.root / "t.txt"], "not a folder"),
    ("run-no-rgb-txt", lambda c: (os.remove(c.seq / "rgb.txt"), ["run", c.seq, "--out", c.root / "t.txt"])[1],
     "rgb.txt: file not found"),
    ("run-undecodable-png", lambda c: (_truncate(c.first("rgb.txt")), ["run", c.seq, "--out", c.root / "t.txt"])[1],
     "does not decode"),
    ("run-8bit-depth", _depth8, "16-bit"),
    ("run-nonnumeric-timestamp", lambda c: ["run", c.edit("rgb.txt", lambda t: t.replace("0.033333 rgb", "x rgb")),
                                            "--out", c.root / "t.txt"], "rgb.txt:5: malformed"),
    ("run-listed-file-missing", lambda c: (os.remove(c.first("depth.txt")), ["run", c.seq, "--out", c.root / "t"])[1],
     "listed in depth.txt"),
    ("run-gt-not-covering", lambda c: ["run", _gt_short(c), "--out", c.root / "t.txt"], "does not cover"),
    ("run-start-past-end", lambda c: ["run", c.seq, "--start", 9, "--out", c.root / "t.txt"], "past the end"),
    ("run-info-json-malformed", lambda c: ["run", c.edit("info.json", lambda t: '{"camera": {"fx": "a"}}'),
                                           "--out", c.root / "t.txt"], "malformed camera entry"),
    ("run-info-json-bad-fx", lambda c: ["run", c.edit("info.json", lambda t: t.replace('"fx": 131.25', '"fx": -1')),
                                        "--out", c.root / "t.txt"], "Camera.fx must be a number > 0"),
    ("run-camera-size-mismatch", lambda c: ["run", c.seq, "--camera", "fr1", "--out", c.root / "t.txt"],
     "the preset fr1 is for 640x480; leave --camera out"),
    ("run-calibration-size-mismatch", lambda c: ["run", c.edit("info.json", _size_640), "--out", c.root / "t.txt"],
     "are for 640x480; write them for 160x120"),
    # --- run: outputs that would destroy inputs
    ("run-out-groundtruth", lambda c: ["run", c.seq, "--out", c.gt], "the input"),
    ("run-out-inside-seq", lambda c: ["run", c.seq, "--out", c.seq / "traj.txt"], "lies inside the input"),
    ("run-out-is-seq", lambda c: ["run", c.seq, "--out", c.seq], "is a directory"),
    ("run-out-is-config", lambda c: ["run", c.seq, "--config", c.write("cfg.json", "{}"), "--out", c.root / "cfg.json"],
     "is the input"),
    ("run-masks-into-true-masks", lambda c: ["run", c.seq, "--save-masks", c.seq / "masks", "--out", c.root / "t"],
     "--save-masks"),
    ("run-out-under-a-file", lambda c: ["run", c.seq, "--out", c.est / "t.txt"], "is a file, not a folder"),
    ("run-save-masks-nonempty", lambda c: ["run", c.seq, "--save-masks", c.write("m/keep.png", "x").parent,
                                           "--out", c.root / "t"], "--save-masks"),
    ("run-batch-out-dir-is-seq", lambda c: ["run", c.seq, _copy(c, "seq2"), "--out-dir", c.seq],
     "lies inside"),
    # --- run: a trajectory header with wrong types
    ("header-frames-str", lambda c: _header(c, '{"frames": "all"}'), 'header field "frames" must be an integer'),
    ("header-depth-scale-str", lambda c: _header(c, '{"depth_scale": "5000"}'), '"depth_scale" must be a number'),
    ("header-start-negative", lambda c: _header(c, '{"start": -1}'), '"start" must be an integer >= 0'),
    ("header-max-dt-bool", lambda c: _header(c, '{"max_dt": true}'), '"max_dt" must be a number'),
    ("header-camera-list", lambda c: _header(c, '{"camera": [1, 2]}'), '"camera" must be a JSON object'),
    ("header-fx-str", lambda c: _header(c, '{"camera": {"fx": "525"}}'), '"camera.fx" must be a number'),
    ("header-seed-str", lambda c: _header(c, '{}', seed='"0"'), 'header field "seed" must be an integer'),
    ("header-sequence-list", lambda c: _header(c, '[1]'), "'# sequence:' header: expected a JSON object"),
    # --- run: options
    ("run-seed-overflow", lambda c: ["run", c.seq, "--seed", "99999999999999999999999"], "--seed"),
    ("run-seed-negative", lambda c: ["run", c.seq, "--seed", "-1"], "--seed"),
    ("run-thresh-lum-negative", lambda c: ["run", c.seq, "--thresh-lum", "-5"], "--thresh-lum"),
    ("run-thresh-depth-zero", lambda c: ["run", c.seq, "--thresh-depth", "0"], "--thresh-depth"),
    ("run-fx-zero", lambda c: ["run", c.seq, "--fx", "0", "--out", c.root / "t"], "Camera.fx"),
    ("run-fy-nan", lambda c: ["run", c.seq, "--fy", "nan", "--out", c.root / "t"], "Camera.fy"),
    ("run-cx-outside", lambda c: ["run", c.seq, "--cx", "10000", "--out", c.root / "t"], "Camera.cx must be a number in"),
    ("run-max-dt-zero", lambda c: ["run", c.seq, "--max-dt", "0"], "--max-dt"),
    ("run-lag-not-below-gap", lambda c: ["run", c.seq, "--keyframe-gap", 3, "--keyframe-lag", 3], "--keyframe-lag"),
    ("run-unknown-method", lambda c: ["run", c.seq, "--method", "lsq"], "--method"),
    ("run-max-frames-1", lambda c: ["run", c.seq, "--max-frames", 1], "--max-frames"),
    ("run-unknown-preset", lambda c: ["run", c.seq, "--camera", "fr9"], "--camera"),
    ("run-unknown-option", lambda c: ["run", c.seq, "--bogus"], "No such option"),
    ("run-missing-argument", lambda c: ["run"], "Missing argument"),
    ("unknown-command", lambda c: ["runn"], "No such command"),
    # --- run: the config file
    ("config-blocks-int", lambda c: _cfg(c, '{"blocks": 4}'), "Config.blocks must be a tuple of integers"),
    ("config-blocks-str", lambda c: _cfg(c, '{"blocks": [4, "x"]}'), "Config.blocks"),
    ("config-finest-level-str", lambda c: _cfg(c, '{"finest_level": "0"}'), "Config.finest_level must be an integer"),
    ("config-thresh-lum-str", lambda c: _cfg(c, '{"thresh_lum": "abc"}'), "Config.thresh_lum must be a number > 0"),
    ("config-thresh-lum-nan", lambda c: _cfg(c, '{"thresh_lum": NaN}'), "got nan"),
    ("config-thresh-lum-null", lambda c: _cfg(c, '{"thresh_lum": null}'), "Config.thresh_lum"),
    ("config-max-depth-negative", lambda c: _cfg(c, '{"max_depth": -1}'), "Config.max_depth"),
    ("config-p-above-1", lambda c: _cfg(c, '{"p": 1.5}'), "Config.p must be a number in (0, 1), got 1.5"),
    ("config-w-negative", lambda c: _cfg(c, '{"w": -0.3}'), "Config.w must be a number in [0, 1)"),
    ("config-min-inlier-ratio-2", lambda c: _cfg(c, '{"min_inlier_ratio": 2}'), "Config.min_inlier_ratio"),
    ("config-n-points-float", lambda c: _cfg(c, '{"n_points": 6.5}'), "Config.n_points must be an integer"),
    ("config-n-points-bool", lambda c: _cfg(c, '{"n_points": true}'), "Config.n_points"),
    ("config-method-unknown", lambda c: _cfg(c, '{"method": "lsq"}'), "Config.method must be one of"),
    ("config-finest-beyond-levels", lambda c: _cfg(c, '{"num_levels": 2, "finest_level": 2}'), "num_levels = 2"),
    ("config-unknown-field", lambda c: _cfg(c, '{"blcoks": [4]}'), "did you mean 'blocks'"),
    ("config-not-object", lambda c: _cfg(c, "[1, 2]"), "expected a JSON object"),
    ("config-not-json", lambda c: _cfg(c, '{"thresh_lum": '), "not valid JSON"),
    ("config-not-utf8", lambda c: ["run", c.seq, "--config", c.write("cfg.json", b'{"p": "\xff"}', True)],
     "not UTF-8"),
    ("config-missing", lambda c: ["run", c.seq, "--config", c.root / "none.json"], "config file not found"),
    ("run-lens-two-numbers", lambda c: ["run", c.seq, "--lens", "0.1,0.2"], "--lens': lens must be 5 finite numbers"),
    ("run-depth-scale-unknown-sensor", lambda c: ["run", c.seq, "--depth-scale", "fr9"],
     "--depth-scale': must be a number > 0, a sensor"),
    ("run-depth-scale-negative", lambda c: ["run", c.seq, "--depth-scale", "-5"],
     "--depth-scale': must be a number > 0"),
    ("config-is-folder", lambda c: ["run", c.seq, "--config", c.seq], "is a folder"),
    # --- eval
    ("eval-missing-estimate", lambda c: ["eval", c.seq, c.root / "none.txt"], "file not found"),
    ("eval-estimate-folder", lambda c: ["eval", c.seq, c.seq], "is a folder"),
    ("eval-estimate-7-fields", lambda c: ["eval", c.seq, c.write("e.txt", "0.0 1 2 3 0 0 0\n")], "got 7"),
    ("eval-estimate-non-numeric", lambda c: ["eval", c.seq, c.write("e.txt", "0.0 1 2 x 0 0 0 1\n")],
     "e.txt:1: malformed"),
    ("eval-estimate-non-finite", lambda c: ["eval", c.seq, c.write("e.txt", "0.0 1 2 inf 0 0 0 1\n")], "non-finite"),
    ("eval-estimate-zero-quaternion", lambda c: ["eval", c.seq, c.write("e.txt", "0.0 1 2 3 0 0 0 0\n")], "zero norm"),
    ("eval-estimate-repeats-stamp", lambda c: ["eval", c.seq, c.write("e.txt", "0.0 0 0 0 0 0 0 1\n"
                                                                       "0.0 1 0 0 0 0 0 1\n")],
     "e.txt:2: timestamp 0.0 repeats line 1"),
    ("eval-estimate-empty", lambda c: ["eval", c.seq, c.write("e.txt", "# nothing\n")], "no poses"),
    ("eval-not-covered", lambda c: ["eval", c.seq, c.write("e.txt", _MOVED_EST)], "does not cover"),
    ("eval-gt-missing", lambda c: ["eval", c.root / "nogt", c.est], "does not exist"),
    ("eval-folder-without-gt", lambda c: (os.remove(c.gt), ["eval", c.seq, c.est])[1], "no ground truth"),
    ("eval-delta-negative", lambda c: ["eval", c.seq, c.est, "--delta", "-1"], "--delta"),
    ("eval-delta-zero", lambda c: ["eval", c.seq, c.est, "--delta", "0"], "--delta"),
    ("eval-delta-unit", lambda c: ["eval", c.seq, c.est, "--delta-unit", "x"], "--delta-unit"),
    ("eval-json-inside-seq", lambda c: ["eval", c.seq, c.est, "--json", c.seq / "r.json"], "--json"),
    ("eval-json-is-estimate", lambda c: ["eval", c.seq, c.est, "--json", c.est], "is the input"),
    ("eval-plot-under-file", lambda c: ["eval", c.seq, c.est, "--plot", c.est / "p.png"], "is a file, not a folder"),
    ("eval-masks-with-gt-file", _masked_gt_file, "needs the sequence folder"),
    ("eval-masks-dir-empty", lambda c: ["eval", c.seq, c.est, "--delta-unit", "f", "--masks-dir",
                                        (c.root / "m").mkdir() or c.root / "m"], "no <timestamp>.png"),
    # --- map
    ("map-out-inside-seq", lambda c: ["map", c.seq, c.est, c.seq / "m.ply"], "lies inside the input"),
    ("map-out-is-traj", lambda c: ["map", c.seq, c.est, c.est], "is the input"),
    ("map-preview-under-file", lambda c: ["map", c.seq, c.est, c.root / "m.ply", "--preview", c.est / "p.png"],
     "is a file, not a folder"),
    ("map-masks-and-no-labels", lambda c: ["map", c.seq, c.est, c.root / "m.ply", "--use-masks", "--no-labels"],
     "exclude each other"),
    ("map-traj-missing", lambda c: ["map", c.seq, c.root / "none.txt", c.root / "m.ply"], "trajectory file not found"),
    ("map-traj-repeats-stamp", lambda c: ["map", c.seq, c.write("e.txt", "0.0 0 0 0 0 0 0 1\n0.0 1 0 0 0 0 0 1\n"),
                                          c.root / "m.ply"], "repeats line 1"),
    ("map-every-zero", lambda c: ["map", c.seq, c.est, c.root / "m.ply", "--every", 0], "--every"),
    ("map-seed-overflow", lambda c: ["map", c.seq, c.est, c.root / "m.ply", "--seed", str(2 ** 70)], "--seed"),
    ("map-outliers-and-hindsight", lambda c: ["map", c.seq, c.est, c.root / "m.ply", "--outliers", "--hindsight"],
     "exclude each other"),
    ("map-camera-size-mismatch", lambda c: ["map", c.seq, c.est, c.root / "m.ply", "--camera", "bonn"],
     "leave --camera out"),
    # --- masks
    ("masks-camera-size-mismatch", lambda c: ["masks", c.seq, c.est, c.root / "mm", "--camera", "fr2"],
     "leave --camera out"),
    ("masks-out-inside-seq", lambda c: ["masks", c.seq, c.est, c.seq / "mm"], "lies inside the input"),
    ("masks-out-nonempty", lambda c: ["masks", c.seq, c.est, c.write("o/x", "keep").parent], "not empty"),
    # --- gt
    ("gt-out-is-groundtruth", lambda c: ["gt", c.seq, "-o", c.gt], "lies inside the input"),
    ("gt-out-inside-seq", lambda c: ["gt", c.seq, "-o", c.seq / "gt_cam.txt"], "lies inside the input"),
    ("gt-out-is-seq", lambda c: ["gt", c.seq, "-o", c.seq], "is a directory"),
    ("gt-out-under-a-file", lambda c: ["gt", c.seq, "-o", c.est / "gt.txt"], "is a file, not a folder"),
    # --- demo
    ("demo-foreign-sequence-folder", lambda c: ["demo", "--out", c.write("d/sequence/mine.txt", "keep").parents[1],
                                                "--frames", 3, "--no-progress"], "was not written by jaxvo"),
    ("demo-out-is-file", lambda c: ["demo", "--out", c.est, "--frames", 3, "--no-progress"], "est.txt"),
    # --- synth
    ("synth-into-sequence", lambda c: ["synth", "seq1", c.seq, "--frames", 2, "--size", "160x120"], "not empty"),
    ("synth-into-file", lambda c: ["synth", "seq1", c.est, "--frames", 2], "is a file"),
    ("synth-frames-1", lambda c: ["synth", "seq1", c.root / "s", "--frames", 1], "--frames"),
    ("synth-unknown-name", lambda c: ["synth", "seq9", c.root / "s"], "seq9"),
    ("synth-seed-negative", lambda c: ["synth", "seq1", c.root / "s", "--seed", "-5"], "--seed"),
    # --- augment
    ("augment-into-itself", lambda c: ["augment", c.seq, c.seq], "is the input"),
    ("augment-inside-itself", lambda c: ["augment", c.seq, c.seq / "aug"], "lies inside the input"),
    ("augment-into-nonempty", lambda c: ["augment", c.seq, (c.root / "o").mkdir() or c.write("o/x", "keep").parent],
     "not empty"),
    ("augment-missing-source", lambda c: ["augment", c.root / "nope", c.root / "aug"], "does not exist"),
    ("augment-no-groundtruth", lambda c: (os.remove(c.gt), ["augment", c.seq, c.root / "aug", "--no-progress"])[1],
     "needs the real ground truth"),
    ("augment-gt-not-covering", lambda c: ["augment", _gt_short(c), c.root / "aug", "--no-progress"],
     "does not cover"),
    ("augment-nonnumeric-timestamp", lambda c: ["augment", c.edit("rgb.txt", lambda t: t.replace("0.033333 rgb", "x rgb")),
                                                c.root / "aug", "--no-progress"], "rgb.txt:5: malformed"),
    ("augment-coverage-above-1", lambda c: ["augment", c.seq, c.root / "aug", "--coverage", 1.5], "--coverage"),
    ("augment-persons-zero", lambda c: ["augment", c.seq, c.root / "aug", "--persons", 0], "--persons"),
]


@pytest.mark.parametrize("build, fragment", [c[1:] for c in CLI_CASES], ids=[c[0] for c in CLI_CASES])
def test_cli_bad_input_one_line_nothing_lost(tmp_path, base_seq, build, fragment):
    c = Case(tmp_path, base_seq)
    args = [str(a) for a in build(c)]
    before = _snapshot(tmp_path)
    r = CliRunner().invoke(main, args, catch_exceptions=False)
    assert r.exit_code == 2, (r.exit_code, r.output)
    err = r.stderr.strip().splitlines()
    assert len(err) == 1, r.stderr
    assert err[0].startswith("error: "), err[0]
    assert fragment in err[0], (fragment, err[0])
    assert "Traceback" not in r.output
    assert _snapshot(tmp_path) == before


# ----------------------------------------------------------------------------- the library

def _frames():
    rng = np.random.default_rng(0)
    f = Frame(rng.uniform(0, 255, (120, 160)).astype(np.float32), np.full((120, 160), 1.5, np.float32))
    return f, f


def _est(**kw):
    ref, cur = _frames()
    args = dict(ref=ref, cur=cur, camera=CAM, config=Config(), key=jax.random.key(0))
    args.update(kw)
    estimate_motion(**args)


@dataclasses.dataclass(frozen=True)
class _Two:
    a: float = 1.0
    b: float = 2.0


LIBRARY_CASES = [
    ("config-n-points-float", lambda: Config(n_points=6.5).validate(), "Config.n_points must be an integer >= 1"),
    ("config-thresh-lum-none", lambda: Config(thresh_lum=None).validate(), "Config.thresh_lum must be a number > 0"),
    ("config-thresh-lum-str", lambda: Config(thresh_lum="30").validate(), "got '30'"),
    ("config-thresh-lum-nan", lambda: Config(thresh_lum=math.nan).validate(), "got nan"),
    ("config-thresh-lum-array", lambda: Config(thresh_lum=np.array([10.0, -1.0])).validate(), "Config.thresh_lum"),
    ("config-p", lambda: Config(p=1.5).validate(), "Config.p must be a number in (0, 1)"),
    ("config-w", lambda: Config(w=-0.3).validate(), "Config.w"),
    ("config-min-inlier-ratio", lambda: Config(min_inlier_ratio=2).validate(), "in [0, 1]"),
    ("config-max-depth", lambda: Config(max_depth=-1.0).validate(), "Config.max_depth"),
    ("config-huber-k", lambda: Config(huber_k=0.0).validate(), "Config.huber_k"),
    ("config-blocks", lambda: Config(blocks=4).validate(), "Config.blocks"),
    ("config-blocks-list", lambda: Config(blocks=[4, 2]).validate(), "Config.blocks"),
    ("config-num-levels", lambda: Config(num_levels=0).validate(), "Config.num_levels"),
    ("config-patch-radius", lambda: Config(patch_radius=-1).validate(), "Config.patch_radius"),
    ("config-bool-as-int", lambda: Config(max_hypotheses=True).validate(), "Config.max_hypotheses"),
    ("config-scoring", lambda: Config(scoring="best").validate(), "Config.scoring must be one of 'count', 'msac'"),
    ("config-replace-unknown", lambda: Config().replace(blcoks=(4,)), "did you mean 'blocks'"),
    ("config-from-dict-list", lambda: Config.from_dict([1]), "expected a JSON object"),
    ("track-config-gap", lambda: TrackConfig(max_gap=0).validate(), "TrackConfig.max_gap"),
    ("track-config-lag", lambda: TrackConfig(max_gap=4, lag=4).validate(), "(max_gap = 4)"),
    ("track-config-flag", lambda: TrackConfig(hold_invalid="yes").validate(), "TrackConfig.hold_invalid"),
    ("track-config-step-deg", lambda: TrackConfig(max_step_deg=500.0).validate(), "TrackConfig.max_step_deg"),
    ("camera-fx-nan", lambda: Camera(math.nan, 525.0, 319.5, 239.5).validate(), "Camera.fx"),
    ("camera-cx-outside", lambda: Camera(525.0, 525.0, 10000.0, 239.5).validate(), "(width = 640)"),
    ("camera-width-float", lambda: Camera(525.0, 525.0, 1.0, 1.0, width=6.5).validate(), "Camera.width"),
    ("camera-fy-str", lambda: Camera(525.0, "525", 319.5, 239.5).validate(), "Camera.fy"),
    ("estimate-key-int", lambda: _est(key=0), "jax.random.key(0)"),
    ("estimate-config-str", lambda: _est(config="ransac"), "jaxvo.Config"),
    ("estimate-camera-str", lambda: _est(camera="fr2"), "jaxvo.Camera"),
    ("estimate-camera-nan", lambda: _est(camera=dataclasses.replace(CAM, fx=math.nan)), "Camera.fx"),
    ("estimate-bad-config", lambda: _est(config=Config(thresh_depth=-1.0)), "Config.thresh_depth"),
    ("track-bad-policy", lambda: track(list(_frames()), CAM, policy=TrackConfig(max_gap=2, lag=5)), "TrackConfig.lag"),
    ("track-key-int", lambda: track(list(_frames()), CAM, key=3), "jax.random.key"),
    ("track-bad-camera", lambda: track(list(_frames()), dataclasses.replace(CAM, cy=-4.0)), "Camera.cy"),
    ("field-without-rule", lambda: check_fields(_Two(), {"a": real()}, "Two"), "no validation rule"),
]


@pytest.mark.parametrize("call, fragment", [c[1:] for c in LIBRARY_CASES], ids=[c[0] for c in LIBRARY_CASES])
def test_library_bad_input_value_error(call, fragment):
    with pytest.raises(ValueError) as e:
        call()
    assert fragment in str(e.value)
    assert "\n" not in str(e.value)


def test_tum_sequence_rejects_a_camera_name(base_seq):
    with pytest.raises(ValueError, match=r"PRESETS\['fr2'\]"):
        TumSequence(base_seq, camera="fr2")


def test_file_name_with_a_space(tmp_path, base_seq):
    c = Case(tmp_path, base_seq)
    first = c.first("rgb.txt")
    spaced = first.with_name("a b.png")
    first.rename(spaced)
    c.edit("rgb.txt", lambda t: t.replace(f"rgb/{first.name}", "rgb/a b.png"))
    seq = TumSequence(c.seq, camera=CAM)
    assert seq.rgb_paths[0] == spaced
    assert seq.frame(0).intensity.shape == (120, 160)


def test_config_rules_cover_every_field():
    from jaxvo.camera import _RULES as CAMERA_RULES
    from jaxvo.config import _RULES, _TRACK_RULES
    assert set(_RULES) == {f.name for f in dataclasses.fields(Config)}
    assert set(_TRACK_RULES) == set(TrackConfig._fields)
    assert set(CAMERA_RULES) == {f.name for f in dataclasses.fields(Camera)}
    Config().validate(), Config.paper().validate(), TrackConfig.keyframes().validate()


# ----------------------------------------------------------------------------- runs that get going

def test_failure_half_way_keeps_the_finished_poses(tmp_path, base_seq):
    """A frame that does not decode in the middle of a run: one error line naming it and the
    .partial file with every pose finished before it; the final name is never written."""
    c = Case(tmp_path, base_seq)
    lines = [ln for ln in (c.seq / "rgb.txt").read_text().splitlines() if ln and not ln.startswith("#")]
    _truncate(c.seq / lines[3].split()[1])
    out = tmp_path / "t.txt"
    r = CliRunner().invoke(main, ["run", str(c.seq), "--out", str(out), "--method", "classic", "--no-progress"],
                           catch_exceptions=False)
    assert r.exit_code == 2, r.output
    err = [ln for ln in r.stderr.strip().splitlines() if not ln.startswith("note:")]
    assert len(err) == 2 and err[0].startswith("jaxvo run:"), r.stderr
    assert "does not decode" in err[1] and "3 finished poses kept in" in err[1] and "t.txt.partial" in err[1]
    assert not out.exists()
    stamps, _ = read_tum_trajectory(tmp_path / "t.txt.partial")
    assert len(stamps) == 3


def _masks(c: Case, dtype) -> Path:
    """A user-mask folder, one PNG per colour frame named like it, every pixel 0 (8-bit) or 1 (16-bit)."""
    import cv2
    d = c.root / "masks"
    d.mkdir()
    for ln in (c.seq / "rgb.txt").read_text().splitlines():
        if ln and not ln.startswith("#"):
            cv2.imwrite(str(d / Path(ln.split()[1]).name), np.full((120, 160), 0 if dtype == np.uint8 else 1, dtype))
    return d


def _batch_bad_frame(c: Case):
    other = _copy(c, "other")
    lines = [ln for ln in (other / "rgb.txt").read_text().splitlines() if ln and not ln.startswith("#")]
    _truncate(other / lines[3].split()[1])
    return ["run", c.seq, other, "--out-dir", c.root / "out"]


#: runs that get going: (id, arguments, exit code, message fragment, trajectories kept: name -> poses)
RUN_CASES = [
    ("batch-bad-frame-stops-only-its-sequence", _batch_bad_frame, 2, "does not decode",
     {"out/seq.txt": 5, "out/other.txt.partial": 3}),
    ("masks-hide-every-pixel", lambda c: ["run", c.seq, "--mask-dir", _masks(c, np.uint8), "--out", c.root / "t.txt"],
     2, "leave 0.0 % of the pixels", {"t.txt": 5}),
    ("masks-16-bit-0-1", lambda c: ["run", c.seq, "--mask-dir", _masks(c, np.uint16), "--out", c.root / "t.txt"],
     2, "a 16-bit 0/1 mask reads as all 0", {"t.txt": 5}),
]


@pytest.mark.parametrize("build, code, fragment, kept", [c[1:] for c in RUN_CASES], ids=[c[0] for c in RUN_CASES])
def test_run_that_gets_going_keeps_what_finished(tmp_path, base_seq, build, code, fragment, kept):
    """A run that fails or produces nothing usable: one error line with the likely cause, its exit
    code, every finished trajectory kept (a complete one under its name, a stopped one as
    .partial), a summary line per sequence and the inputs untouched."""
    c = Case(tmp_path, base_seq)
    args = [str(a) for a in build(c)] + ["--method", "classic", "--no-progress"]
    before = {d: _snapshot(d) for d in tmp_path.iterdir() if d.is_dir()}
    r = CliRunner().invoke(main, args, catch_exceptions=False)
    assert r.exit_code == code, r.output
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and fragment in errors[0], r.stderr
    assert "Traceback" not in r.output
    for name, n in kept.items():
        assert len(read_tum_trajectory(tmp_path / name)[0]) == n, name
        if name.endswith(".partial"):
            assert not (tmp_path / name[:-len(".partial")]).exists(), name
    if len(kept) > 1:
        assert [ln.split(":")[0] for ln in r.stdout.splitlines()] == ["seq", "other"], r.stdout
    assert {d: _snapshot(d) for d in before} == before


def test_interrupted_demo_keeps_the_previous_files(tmp_path):
    """Ctrl-C while the demo renders: the previous complete trajectory and sequence stay as they
    were; only .partial names hold the unfinished work."""
    from jaxvo.pipelines.demo import run_demo
    from jaxvo.synthetic import generate

    out = tmp_path / "demo"
    generate("seq1", out / "sequence", frames=3, seed=1, camera=CAM)       # jaxvo's, another scene
    (out / "traj_classic.txt").write_text("# complete\n0.0 0 0 0 0 0 0 1\n")
    before = _snapshot(out)

    def stop():
        raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        run_demo(out, frames=4, seq_name="seq2", size="64x48", progress=False, methods=("classic",), check=stop)
    after = _snapshot(out)
    assert {k: after.get(k) for k in before} == before
    assert (out / "sequence.partial").is_dir()


def _proc(args, **kw):
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    return subprocess.Popen([sys.executable, "-m", "jaxvo_launch", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env, cwd=REPO, **kw)


def test_damaged_png_gives_only_our_line(tmp_path, base_seq):
    """libpng / OpenCV print their own warnings for a truncated PNG; the command shows only its line."""
    c = Case(tmp_path, base_seq)
    _truncate(c.first("rgb.txt"))
    p = _proc(["run", c.seq, "--out", tmp_path / "t.txt", "--no-progress"])
    out, err = p.communicate(timeout=120)
    assert p.returncode == 2, err
    assert err.strip().splitlines() == [err.strip()] and err.startswith("error: ") and "does not decode" in err


def test_ctrl_c_while_starting_and_while_compiling(tmp_path, base_seq):
    # while Python / JAX load: exit 130 at once, one line, no traceback
    p = _proc(["run", base_seq, "--out", tmp_path / "a.txt", "--no-progress"])
    time.sleep(0.3)
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert "Traceback" not in err and "interrupted" in err
    # while the first pair compiles: exit 130, the summary, the first pose kept, no crash
    p = _proc(["run", base_seq, "--out", tmp_path / "b.txt", "--no-progress"])
    t0 = time.time()
    while not (tmp_path / "b.txt.partial").exists() and time.time() - t0 < 120:
        time.sleep(0.05)
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert "Traceback" not in err and "Segmentation" not in err
    assert "interrupted (Ctrl-C)" in out and "b.txt.partial" in out
    assert not (tmp_path / "b.txt").exists()
    assert len(read_tum_trajectory(tmp_path / "b.txt.partial")[0]) >= 1
