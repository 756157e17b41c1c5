"""``jaxvo map``: a PLY map + preview from a 3-frame synthetic sequence, and bad input -> exit 2."""
from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from jaxvo.camera import DEFAULT
from jaxvo.cli.main import main
from jaxvo.data.ply import read_ply, read_ply_vertices
from jaxvo.pipelines.mapping import MOVING_COLOUR
from jaxvo.data.trajectory import read_tum_trajectory, write_tum_trajectory


def _runner():
    return CliRunner()


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    from jaxvo.synthetic import generate
    d = generate("seq1", tmp_path_factory.mktemp("climap") / "seq1", frames=3, seed=0, camera=DEFAULT.at_level(2))
    t, T = read_tum_trajectory(d / "groundtruth.txt")
    write_tum_trajectory(d.parent / "traj.txt", t, T)
    return d


@pytest.mark.parametrize("labels, said", [([], "labels hindsight"), (["--no-labels"], "labels none")])
def test_map_default_labels_are_the_segmentation_stored_as_a_property(seq, tmp_path, labels, said):
    out = tmp_path / "map.ply"
    r = _runner().invoke(main, ["map", str(seq), str(seq.parent / "traj.txt"), str(out), "--every", "1",
                                "--no-progress", *labels])
    assert r.exit_code == 0, r.output + r.stderr
    assert said in r.stderr
    assert ("moving" in read_ply_vertices(out)) == (not labels)


def test_map_estimated_labels(seq, tmp_path):
    out, png = tmp_path / "map.ply", tmp_path / "map.png"
    r = _runner().invoke(main, ["map", str(seq), str(seq.parent / "traj.txt"), str(out), "--every", "1",
                                "--method", "classic", "--outliers", "--preview", str(png), "--no-progress"])
    assert r.exit_code == 0, r.output + r.stderr
    P, C = read_ply(out)
    assert len(P) > 1000 and C.shape == P.shape
    assert f"points        {len(P)} after a 0.01 m voxel grid" in r.output
    assert "inlier ratio" in r.output
    assert png.stat().st_size > 5000


def test_map_masks_colours_moving_points(seq, tmp_path):
    out = tmp_path / "m.ply"
    r = _runner().invoke(main, ["map", str(seq), str(seq.parent / "traj.txt"), str(out), "--use-masks",
                                "--voxel", "0", "--max-frames", "2", "--no-progress"])
    assert r.exit_code == 0, r.output + r.stderr
    P, C = read_ply(out)
    green = np.all(C == np.asarray(MOVING_COLOUR, np.uint8), axis=1)
    assert 0 < green.sum() < len(P)
    np.testing.assert_array_equal(read_ply_vertices(out)["moving"], green)
    assert "frames        1 used (every 5 of 2" in r.output


@pytest.mark.parametrize("case", ["no-seq", "no-traj", "bad-traj", "no-overlap"])
def test_map_bad_input(seq, tmp_path, case):
    traj = seq.parent / "traj.txt"
    sdir = seq
    if case == "no-seq":
        sdir = tmp_path / "missing"
    elif case == "no-traj":
        traj = tmp_path / "missing.txt"
    elif case == "bad-traj":
        traj = tmp_path / "bad.txt"
        traj.write_text("1.0 2.0 three\n")
    else:
        traj = tmp_path / "far.txt"
        traj.write_text("1000.0 0 0 0 0 0 0 1\n")
    r = _runner().invoke(main, ["map", str(sdir), str(traj), str(tmp_path / "x.ply"), "--use-masks",
                                "--no-progress"])
    assert r.exit_code == 2
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("error: ")]
    assert len(errors) == 1 and r.stderr.rstrip().endswith(errors[0]) and "Traceback" not in r.stderr
    assert not (tmp_path / "x.ply").exists()
