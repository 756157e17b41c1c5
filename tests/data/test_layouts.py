"""Recordings that are not 640x480 TUM folders: other sizes, millimetre depth, calibration files,
the ICL-NUIM and Redwood layouts, and the depth-scale plausibility check (library and CLI)."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from jaxvo.camera import DEFAULT, camera_for_size
from jaxvo.cli.main import main
from jaxvo.data import (DatasetError, IclNuimSequence, RedwoodSequence, TumSequence, check_depth_scale,
                            open_sequence)
from jaxvo.data.trajectory import read_tum_trajectory

W, H = 424, 240
FRAMES = 4


@pytest.fixture(scope="module")
def seq424(tmp_path_factory):
    """A 424x240 synthetic TUM folder (as `jaxvo synth seq2 --size 424x240` writes) whose depth PNGs
    are rounded to whole millimetres (multiples of 5 at TUM's 5000 per metre), so that a
    millimetre copy holds exactly the same depths."""
    from jaxvo.synthetic import generate

    d = tmp_path_factory.mktemp("layouts") / "s424"
    generate("seq2", d, frames=FRAMES, seed=0, camera=camera_for_size(DEFAULT, W, H))
    for p in sorted((d / "depth").glob("*.png")):
        z = cv2.imread(str(p), cv2.IMREAD_UNCHANGED).astype(np.int64)
        cv2.imwrite(str(p), (np.rint(z / 5.0) * 5).astype(np.uint16))
    return d


def _copy(src: Path, dst: Path, depth_div: int = 1, keep=("rgb.txt", "depth.txt", "groundtruth.txt", "info.json")):
    """The folder's images (depth divided by depth_div) and the listed text files."""
    (dst / "rgb").mkdir(parents=True)
    (dst / "depth").mkdir()
    for p in (src / "rgb").glob("*.png"):
        shutil.copy(p, dst / "rgb" / p.name)
    for p in (src / "depth").glob("*.png"):
        z = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(dst / "depth" / p.name), (z // depth_div).astype(np.uint16))
    for f in keep:
        if (src / f).is_file():
            shutil.copy(src / f, dst / f)
    return dst


def _run(seq_dir, out, *extra):
    r = CliRunner().invoke(main, ["run", str(seq_dir), "--out", str(out), "--method", "classic", "--no-progress",
                                  *extra])
    return r


def test_424x240_millimetre_copy_and_eth3d_calibration_give_the_same_trajectory(seq424, tmp_path):
    r = _run(seq424, tmp_path / "orig.txt")
    assert r.exit_code == 0, r.output
    t0, P0 = read_tum_trajectory(tmp_path / "orig.txt")
    assert len(t0) == FRAMES

    mm = _copy(seq424, tmp_path / "mm", depth_div=5)
    r = _run(mm, tmp_path / "mm_bad.txt")
    assert r.exit_code == 2
    err = r.output.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "--depth-scale 1000" in err[0], r.output
    r = _run(mm, tmp_path / "mm.txt", "--depth-scale", "1000")
    assert r.exit_code == 0, r.output
    t1, P1 = read_tum_trajectory(tmp_path / "mm.txt")
    np.testing.assert_array_equal(t1, t0)
    np.testing.assert_allclose(P1, P0, atol=1e-9)

    # ETH3D: TUM layout plus calibration.txt "fx fy cx cy", no info.json; the size comes from the images
    eth = _copy(seq424, tmp_path / "eth3d", keep=("rgb.txt", "depth.txt", "groundtruth.txt"))
    c = camera_for_size(DEFAULT, W, H)
    (eth / "calibration.txt").write_text(f"{c.fx} {c.fy} {c.cx} {c.cy}\n")
    seq = open_sequence(eth)
    assert seq.camera == c and seq.camera_source == "calibration.txt"
    r = _run(eth, tmp_path / "eth.txt")
    assert r.exit_code == 0, r.output
    np.testing.assert_allclose(read_tum_trajectory(tmp_path / "eth.txt")[1], P0, atol=1e-9)


def test_no_calibration_scales_the_preset_to_the_images_and_says_so(seq424, tmp_path):
    bare = _copy(seq424, tmp_path / "bare", keep=("rgb.txt", "depth.txt"))
    seq = open_sequence(bare)
    assert seq.camera == camera_for_size(DEFAULT, W, H)
    assert seq.camera_source.startswith("a guess") and "424x240" in seq.camera_source
    seq = open_sequence(bare, camera=DEFAULT)          # a 640x480 camera on 424x240 images
    with pytest.raises(DatasetError, match="does not match the camera"):
        seq.frame(0)


def test_icl_nuim_associations(seq424, tmp_path):
    ref = TumSequence(seq424)
    icl = _copy(seq424, tmp_path / "icl", keep=("info.json",))
    lines = [f"{td:.6f} {dp.parent.name}/{dp.name} {tr:.6f} {rp.parent.name}/{rp.name}"
             for tr, td, rp, dp in zip(ref.timestamps, ref.depth_timestamps, ref.rgb_paths, ref.depth_paths)]
    (icl / "associations.txt").write_text("\n".join(lines[::-1]) + "\n")   # depth first, any order
    shutil.copy(seq424 / "groundtruth.txt", icl / "living_room.gt.freiburg")
    seq = open_sequence(icl)
    assert isinstance(seq, IclNuimSequence) and len(seq) == FRAMES
    np.testing.assert_array_equal(seq.timestamps, ref.timestamps)
    np.testing.assert_array_equal(seq.frame(2).depth, ref.frame(2).depth)
    np.testing.assert_array_equal(seq.frame(2).intensity, ref.frame(2).intensity)
    np.testing.assert_array_equal(seq.groundtruth[1], ref.groundtruth[1])


def test_redwood_folders_millimetres_and_open3d_intrinsics(seq424, tmp_path):
    ref = TumSequence(seq424)
    rw = tmp_path / "redwood"
    (rw / "color").mkdir(parents=True)
    (rw / "depth").mkdir()
    for k, (rp, dp) in enumerate(zip(ref.rgb_paths, ref.depth_paths)):
        shutil.copy(rp, rw / "color" / f"{k:06d}.png")
        z = cv2.imread(str(dp), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(rw / "depth" / f"{k:06d}.png"), (z // 5).astype(np.uint16))
    c = camera_for_size(DEFAULT, W, H)
    (rw / "camera_intrinsic.json").write_text(json.dumps(
        {"width": W, "height": H, "intrinsic_matrix": [c.fx, 0, 0, 0, c.fy, 0, c.cx, c.cy, 1]}))
    seq = open_sequence(rw)
    assert isinstance(seq, RedwoodSequence) and len(seq) == FRAMES and seq.depth_scale == 1000
    assert seq.camera == c and seq.camera_source == "camera_intrinsic.json"
    np.testing.assert_allclose(np.diff(seq.timestamps), 1 / 30)
    np.testing.assert_array_equal(seq.frame(1).depth, ref.frame(1).depth)


def test_unknown_layout_is_one_clear_error(tmp_path):
    (tmp_path / "x").mkdir()
    with pytest.raises(DatasetError, match="not an RGB-D sequence folder"):
        open_sequence(tmp_path / "x")
    r = CliRunner().invoke(main, ["run", str(tmp_path / "x"), "--no-progress"])
    assert r.exit_code == 2 and r.output.startswith("error:") and "associations.txt" in r.output


# millimetres read as TUM's 1/5000 m come out 5x too small (0.5 m for a 2.5 m scene: caught when the
# scale is the layout's default, accepted when passed explicitly); TUM depth read as millimetres
# comes out 5x too large, which leaves the plausible range only for far scenes (12 m here)
@pytest.mark.parametrize("median_m, scale, explicit, suggest", [
    (0.5, 5000.0, False, 1000), (0.5, 5000.0, True, None), (12.0, 1000.0, True, 5000), (12.0, 1000.0, False, 5000),
    (2.0, 5000.0, False, None), (0.198, 5000.0, True, 1000)])
def test_depth_scale_check_names_the_scale_to_pass(median_m, scale, explicit, suggest):
    z = np.full((10, 10), median_m, np.float32)
    z[0] = 0.0
    if suggest is None:
        check_depth_scale(z, scale, "f.png", explicit)
        return
    raw = median_m * scale
    with pytest.raises(DatasetError) as e:
        check_depth_scale(z, scale, "f.png", explicit)
    msg = str(e.value)
    assert msg.startswith("f.png:") and "\n" not in msg
    assert f"--depth-scale {suggest}" in msg and 0.2 <= raw / suggest <= 10


def test_mask_dir_fills_frame_mask_and_changes_the_trajectory(seq424, tmp_path):
    """User masks (nonzero = usable), here 0 on the synthetic person, named like the colour images:
    the reader fills Frame.mask, and `jaxvo run --mask-dir` gives another trajectory than without."""
    ref = TumSequence(seq424)
    md = tmp_path / "usable"
    md.mkdir()
    true = {}
    for rp, (t, mp) in zip(ref.rgb_paths, zip(*_true_masks(seq424))):
        person = cv2.imread(str(mp), cv2.IMREAD_GRAYSCALE) > 127
        true[rp.stem] = person
        cv2.imwrite(str(md / f"{rp.stem}.png"), np.where(person, 0, 255).astype(np.uint8))
    seq = open_sequence(seq424, mask_dir=md)
    f = seq.frame(1)
    assert f.mask.dtype == bool and f.mask.shape == (H, W)
    np.testing.assert_array_equal(f.mask, ~true[seq.rgb_paths[1].stem])
    assert open_sequence(seq424).frame(1).mask is None

    r0 = _run(seq424, tmp_path / "plain.txt")
    r1 = _run(seq424, tmp_path / "masked.txt", "--mask-dir", str(md))
    assert r0.exit_code == 0 and r1.exit_code == 0, (r0.output, r1.output)
    P0 = read_tum_trajectory(tmp_path / "plain.txt")[1]
    P1 = read_tum_trajectory(tmp_path / "masked.txt")[1]
    assert np.abs(P1[1:, :3, 3] - P0[1:, :3, 3]).max() > 1e-5

    bad = tmp_path / "nomatch"
    bad.mkdir()
    cv2.imwrite(str(bad / "zzz.png"), np.zeros((H, W), np.uint8))
    r = _run(seq424, tmp_path / "x.txt", "--mask-dir", str(bad))
    assert r.exit_code == 2 and r.output.startswith("error:") and "no mask PNG matches" in r.output


def _true_masks(seq_dir):
    from jaxvo.evaluation.scoring import true_masks

    return true_masks(seq_dir)
