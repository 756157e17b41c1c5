"""Moving-pixel masks in hindsight (``jaxvo.tracking.hindsight``, ``jaxvo masks``): one view's votes on
hand-made depth and luminance, the per-frame decision with its 3-D regions, the sequence loop
on a synthetic sequence with exact masks and poses, and the command."""
from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from jaxvo.tracking import hindsight
from jaxvo.camera import DEFAULT
from jaxvo.cli.main import main
from jaxvo.data import TumSequence
from jaxvo.evaluation.scoring import read_mask_dir
from jaxvo.pipelines.mapping import load_mask, read_moving_masks
from jaxvo.data.trajectory import read_tum_trajectory, write_tum_trajectory

CAM = DEFAULT.at_level(2)      # 160x120
H, W = CAM.height, CAM.width


def _texture(seed=0):
    rng = np.random.default_rng(seed)
    # smooth enough that its gradient stays under the edge tolerance, varied enough to see a shift
    coarse = rng.uniform(60, 200, (H // 8 + 1, W // 8 + 1))
    return np.kron(coarse, np.ones((8, 8)))[:H, :W].astype(np.float32)


def _votes(ref_int, ref_depth, view_int, view_depth, T=np.eye(4, dtype=np.float32)):
    ref = hindsight.frame_level(ref_int, ref_depth)
    view = hindsight.frame_level(view_int, view_depth)
    seen, changed = hindsight.view_votes(ref, view, T, CAM, 30.0, 0.05)
    return np.asarray(seen), np.asarray(changed)


def test_view_votes_on_hand_made_depth_and_luminance():
    """A wall at 2 m seen from the same pose: where the view has a surface 1 m nearer the pixel is
    hidden (not seen); where it is 1 m farther (the point left) it changed; where the luminance
    jumps by 120 it changed; the rest is seen and kept, although the whole view is 20 grey levels
    brighter (the pair's exposure offset)."""
    inten = _texture()
    depth = np.full((H, W), 2.0, np.float32)
    v_int, v_depth = inten + 20.0, depth.copy()
    v_depth[10:30, 10:40] = 1.0          # something stepped in front
    v_depth[60:80, 10:40] = 3.0          # the point is gone: the view sees behind it
    v_int[60:80, 90:120] += 120.0        # same depth, other appearance (beyond the texture's edges)
    seen, changed = _votes(inten, depth, v_int, v_depth)
    inner = (slice(12, 28), slice(12, 38)), (slice(62, 78), slice(12, 38)), (slice(62, 78), slice(92, 118))
    assert not seen[inner[0]].any() and not changed[inner[0]].any()
    assert seen[inner[1]].all() and changed[inner[1]].all()
    assert seen[inner[2]].all() and changed[inner[2]].all()
    rest = np.ones((H, W), bool)
    for a, b in ((slice(8, 32), slice(8, 42)), (slice(58, 82), slice(8, 42)), (slice(58, 82), slice(88, 122))):
        rest[a, b] = False
    rest[:, -2:] = rest[-2:, :] = False  # the last row / column: bilinear samples beyond the image
    assert seen[rest].mean() > 0.99 and changed[rest].mean() < 0.01


def test_view_votes_follow_the_pose():
    """A view 12 cm to the side sees the same wall: at the right T_view_ref nothing changes, at
    the identity (the wrong pose) the texture no longer lines up."""
    inten = _texture(1)
    depth = np.full((H, W), 2.0, np.float32)
    shift = 8
    T = np.eye(4, dtype=np.float32)
    T[0, 3] = -shift * 2.0 / CAM.fx   # view x = reference x - 0.12 m: the image moves 8 pixels left
    v_int = np.zeros_like(inten)
    v_int[:, :W - shift] = inten[:, shift:]
    _, changed_right = _votes(inten, depth, v_int, depth, T)
    _, changed_wrong = _votes(inten, depth, v_int, depth)
    assert changed_right[:, shift + 2:W - shift - 2].mean() < 0.02
    assert changed_wrong[:, shift + 2:W - shift - 2].mean() > 0.3


def test_decide_ratio_and_regions():
    """Changed in >= ratio of the seeing views is moving; a blob 1 m in front of a wall, 60 % of
    its pixels moving all over it, is flagged whole (region_ratio 0.5: every 3-D region of it is
    mostly moving) and the wall stays; never-seen pixels of the wall stay unflagged; pixels
    without depth are never moving."""
    depth = np.full((H, W), 3.0, np.float32)
    depth[40:80, 60:100] = 1.0
    n_seen = np.full((H, W), 4, np.int32)
    n_changed = np.zeros((H, W), np.int32)
    r, c = np.mgrid[0:H, 0:W]
    n_changed[((r + c) % 5 < 3) & (depth == 1.0)] = 1     # 1 of 4 views: exactly ratio 0.25
    n_seen[0:10, :] = 0                   # never seen
    n_changed[0:10, :] = 0
    n_changed[100:110, 0:5] = 4           # a few wall pixels changed: too few for their region
    depth[115:, :] = 0.0                  # no depth
    n_changed[115:, :] = 4
    p = hindsight.HindsightParams()
    m = np.asarray(hindsight.decide(n_seen, n_changed, depth, CAM, p))
    assert m[40:80, 60:100].all()                                 # the whole blob
    assert m[100:110, 0:5].all()                                  # moving by its own votes
    assert not m[115:].any()
    wall = (depth == 3.0)
    wall[100:110, 0:5] = False
    assert not m[wall].any()
    strict = np.asarray(hindsight.decide(n_seen, n_changed, depth, CAM, p._replace(ratio=0.3, region_ratio=0.9)))
    assert not strict[40:80, 60:100].any() and strict[100:110, 0:5].all()


@pytest.fixture(scope="module")
def seq1(tmp_path_factory):
    """seq1 at 160x120 (fixed camera, one person walking), 40 frames, exact masks and poses."""
    from jaxvo.synthetic import generate
    d = generate("seq1", tmp_path_factory.mktemp("hindsight") / "seq1", frames=40, seed=0, camera=CAM)
    t, T = read_tum_trajectory(d / "groundtruth.txt")
    write_tum_trajectory(d.parent / "traj.txt", t, T)
    return d


def _true_masks(d):
    seq = TumSequence(d)
    mt, mp = read_moving_masks(d)
    return seq, [load_mask(mp[int(np.argmin(np.abs(mt - t)))], (H, W)) for t in seq.timestamps]


def test_sequence_masks_find_the_person(seq1):
    """With the true poses, the walking person is found with precision and recall >= 0.8 over the
    frames (pixels with depth), each frame is read once, and a frame without a pose is neither
    decided nor used as a view."""
    seq, true = _true_masks(seq1)
    poses = seq.groundtruth_at_frames()[1]
    calls = []

    def frame_at(i):
        calls.append(i)
        return seq.frame(i)

    out = dict(hindsight.sequence_masks(frame_at, poses, seq.camera))
    assert sorted(out) == list(range(len(seq)))
    assert sorted(calls) == list(range(len(seq)))          # each frame loaded once
    tp = fp = fn = 0
    for i, m in out.items():
        valid = np.asarray(seq.frame(i).depth) > 0
        tp += (m & true[i] & valid).sum()
        fp += (m & ~true[i] & valid).sum()
        fn += (~m & true[i] & valid).sum()
    assert tp / (tp + fp) >= 0.8 and tp / (tp + fn) >= 0.8, (tp, fp, fn)

    gap = poses.copy()
    gap[20] = np.nan
    calls.clear()
    out2 = dict(hindsight.sequence_masks(frame_at, gap, seq.camera, offsets=(-4, 4)))
    assert 20 not in out2 and 20 not in calls
    # frames 16 and 24 had frame 20 as a view; the others are as before with the same offsets
    ref = dict(hindsight.sequence_masks(seq.frame, poses, seq.camera, offsets=(-4, 4)))
    assert all(np.array_equal(out2[i], ref[i]) for i in out2 if i not in (16, 24))


def test_sequence_masks_bad_arguments():
    """Refused when called, before any mask is asked for (nothing to iterate)."""
    with pytest.raises(ValueError, match="poses must be"):
        hindsight.sequence_masks(lambda i: None, np.eye(4), CAM)
    with pytest.raises(ValueError, match="offsets"):
        hindsight.sequence_masks(lambda i: None, np.eye(4)[None], CAM, offsets=(0,))
    with pytest.raises(ValueError, match="frame_at must be a function i -> Frame .* got int"):
        hindsight.sequence_masks(3, np.eye(4)[None], CAM)
    with pytest.raises(ValueError, match=r"frames must be indices of the 2 poses, got \[-1, 2\]"):
        hindsight.sequence_masks(lambda i: None, np.eye(4)[None].repeat(2, 0), CAM, frames=[0, -1, 2])


def test_sequence_masks_of_a_list_of_frames_are_those_of_frame_at(seq1):
    seq = TumSequence(seq1)
    poses = seq.groundtruth_at_frames()[1][:8]
    frames = [seq.frame(i) for i in range(8)]
    by_list = dict(hindsight.sequence_masks(frames, poses, seq.camera, offsets=(-2, 2)))
    by_call = dict(hindsight.sequence_masks(seq.frame, poses, seq.camera, offsets=(-2, 2)))
    assert sorted(by_list) == list(range(8)) and all(np.array_equal(by_list[i], by_call[i]) for i in by_call)


def test_masks_command_writes_what_eval_scores(seq1, tmp_path):
    out = tmp_path / "masks"
    r = CliRunner().invoke(main, ["masks", str(seq1), str(seq1.parent / "traj.txt"), str(out), "--max-frames", "12",
                                  "--offsets", "-8,-4,4,8", "--no-progress"])
    assert r.exit_code == 0, r.output + r.stderr
    stamps, paths = read_mask_dir(out)
    assert len(paths) == 12 and not (tmp_path / "masks.partial").exists()
    assert np.allclose(stamps, TumSequence(seq1).timestamps[:12], atol=1e-6)
    assert "wrote 12 masks" in r.output
    r = CliRunner().invoke(main, ["eval", str(seq1), str(seq1.parent / "traj.txt"), "--masks-dir", str(out)])
    assert r.exit_code == 0, r.output + r.stderr
    assert "outlier mask vs true moving pixels (12 frames)" in r.output


def test_masks_command_leaves_held_poses_out(seq1, tmp_path):
    """A pose that 'jaxvo run' marked held (# held) gets no mask and the others are still written."""
    t, T = read_tum_trajectory(seq1.parent / "traj.txt")
    traj = tmp_path / "held.txt"
    lines = (seq1.parent / "traj.txt").read_text().splitlines()
    data = [i for i, ln in enumerate(lines) if ln and not ln.startswith("#")]
    lines.insert(data[5], f"# held {lines[data[5]].split()[0]}")
    traj.write_text("\n".join(lines) + "\n")
    out = tmp_path / "m"
    r = CliRunner().invoke(main, ["masks", str(seq1), str(traj), str(out), "--max-frames", "10", "--offsets", "-4,4",
                                  "--no-progress"])
    assert r.exit_code == 0, r.output + r.stderr
    stamps, _ = read_mask_dir(out)
    assert len(stamps) == 9 and not np.isclose(stamps, t[5], atol=1e-6).any()
    assert "(1 held poses of" in r.stderr


def test_masks_command_keeps_what_it_wrote_when_a_frame_is_bad(seq1, tmp_path):
    """A depth image that does not decode half way stops the command with one error line naming the
    file; the masks decided before it stay in OUT_DIR.partial, and the line says so. (A blank one,
    a covered sensor's, is a frame without depth: it sees nothing, and the command goes on.)"""
    import shutil

    import cv2
    d = tmp_path / "seq"
    shutil.copytree(seq1, d)
    bad = TumSequence(d).depth_paths[6]
    cv2.imwrite(str(bad), np.zeros((H, W), np.uint16))
    r = CliRunner().invoke(main, ["masks", str(d), str(seq1.parent / "traj.txt"), str(tmp_path / "blank"),
                                  "--max-frames", "10", "--offsets", "-2,2", "--no-progress"])
    assert r.exit_code == 0, r.output + r.stderr
    bad.write_bytes(b"not a png")
    r = CliRunner().invoke(main, ["masks", str(d), str(seq1.parent / "traj.txt"), str(tmp_path / "m"),
                                  "--max-frames", "10", "--offsets", "-2,2", "--no-progress"])
    assert r.exit_code == 2
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("error: ")]
    assert len(errors) == 1 and str(bad) in errors[0] and "finished masks kept in" in errors[0]
    kept = list((tmp_path / "m.partial").glob("*.png"))
    assert len(kept) == 4 and not (tmp_path / "m").exists()     # frames 0-3; frame 4 needs frame 6


@pytest.mark.parametrize("case", ["offsets", "zero-offsets", "no-traj", "no-overlap", "not-empty"])
def test_masks_command_bad_input(seq1, tmp_path, case):
    args = ["masks", str(seq1), str(seq1.parent / "traj.txt"), str(tmp_path / "out"), "--no-progress"]
    if case == "offsets":
        args += ["--offsets", "4,x"]
    elif case == "zero-offsets":
        args += ["--offsets", "0"]
    elif case == "no-traj":
        args[2] = str(tmp_path / "missing.txt")
    elif case == "no-overlap":
        far = tmp_path / "far.txt"
        far.write_text("1000.0 0 0 0 0 0 0 1\n")
        args[2] = str(far)
    else:
        (tmp_path / "out").mkdir()
        (tmp_path / "out" / "keep.png").write_bytes(b"x")
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2, r.output + r.stderr
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("error: ")]
    assert len(errors) == 1 and "Traceback" not in r.stderr
    assert case == "not-empty" or not (tmp_path / "out").exists()


def test_map_with_hindsight_labels(seq1, tmp_path):
    """``jaxvo map --hindsight`` paints the moving points of the frames used from the hindsight masks
    (every matched frame a view): the person's share of the map's points is near its share of the
    frames' valid pixels, and the static room stays in its colours."""
    from jaxvo.data.ply import read_ply
    from jaxvo.pipelines.mapping import MOVING_COLOUR
    out = tmp_path / "m.ply"
    r = CliRunner().invoke(main, ["map", str(seq1), str(seq1.parent / "traj.txt"), str(out), "--hindsight",
                                  "--every", "10", "--voxel", "0", "--no-progress"])
    assert r.exit_code == 0, r.output + r.stderr
    P, C = read_ply(out)
    green = np.all(C == np.asarray(MOVING_COLOUR, np.uint8), axis=1)
    seq, true = _true_masks(seq1)
    share = np.mean([true[i][np.asarray(seq.frame(i).depth) > 0].mean() for i in range(0, len(seq), 10)])
    assert 0.0 < share and abs(green.mean() - share) < 0.3 * share, (green.mean(), share)
    r = CliRunner().invoke(main, ["map", str(seq1), str(seq1.parent / "traj.txt"), str(tmp_path / "x.ply"),
                                  "--hindsight", "--use-masks", "--no-progress"])
    assert r.exit_code == 2 and "exclude each other" in r.stderr


def test_depth_tolerance_grows_with_depth():
    """A wall 3.5 m away that a view sees 8 cm farther (a disparity step there, or a pose a few
    tenths of a degree off) changed with the flat 5 cm tolerance, not with depth_slope 0.01
    (5 + 12 cm there); a wall 1 m away seen 8 cm farther changed with either."""
    inten = _texture(2)
    for z, flat, grown in ((3.5, True, False), (1.0, True, True)):
        depth = np.full((H, W), z, np.float32)
        ref = hindsight.frame_level(inten, depth)
        view = hindsight.frame_level(inten, depth + 0.08)
        for slope, expect in ((0.0, flat), (0.01, grown)):
            seen, changed = (np.asarray(x) for x in hindsight.view_votes(ref, view, np.eye(4, dtype=np.float32), CAM,
                                                                        30.0, 0.05, slope))
            inner = (slice(2, H - 2), slice(2, W - 2))
            assert seen[inner].all() and changed[inner].all() == expect and changed[inner].any() == expect


def test_run_marks_a_failed_frame_held(seq1, tmp_path):
    """'jaxvo run' writes '# held <stamp>' before the pose of a frame whose estimate failed (here a
    frame of noise), and only there; the trajectory readers still read every pose."""
    import shutil

    import cv2

    from jaxvo.data.trajectory import read_held
    d = tmp_path / "seq"
    shutil.copytree(seq1, d)
    seq = TumSequence(d)
    rng = np.random.default_rng(0)
    cv2.imwrite(str(seq.rgb_paths[3]), rng.integers(0, 255, (H, W, 3), dtype=np.uint8))
    cv2.imwrite(str(seq.depth_paths[3]), rng.integers(2500, 15000, (H, W), dtype=np.uint16))
    out = tmp_path / "traj.txt"
    r = CliRunner().invoke(main, ["run", str(d), "--out", str(out), "--max-frames", "6", "--no-progress"])
    assert r.exit_code == 0, r.output + r.stderr
    assert np.allclose(read_held(out), [seq.timestamps[3]], atol=1e-6)
    assert len(read_tum_trajectory(out)[0]) == 6
