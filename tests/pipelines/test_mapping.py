"""jaxvo.pipelines.mapping: PLY round trip, back-projection onto known geometry, voxel grid, map building."""
from __future__ import annotations

import numpy as np
import pytest

from jaxvo.data import ply
from jaxvo.pipelines import mapping
from jaxvo.camera import DEFAULT
from jaxvo.data import DatasetError, TumSequence
from jaxvo.data.trajectory import read_tum_trajectory

CAM = DEFAULT.at_level(2)   # 160x120: fast to render


@pytest.fixture(scope="module")
def seq1_dir(tmp_path_factory):
    from jaxvo.synthetic import generate
    return generate("seq1", tmp_path_factory.mktemp("map") / "seq1", frames=3, seed=0, camera=CAM)


def test_ply_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    P = rng.normal(size=(1234, 3)).astype(np.float32) * 3
    C = rng.integers(0, 256, size=(1234, 3), dtype=np.uint8)
    path = ply.write_ply(tmp_path / "c.ply", P, C)
    assert path.read_bytes().startswith(b"ply\nformat binary_little_endian 1.0\n")
    P2, C2 = ply.read_ply(path)
    assert P2.shape == (1234, 3) and C2.shape == (1234, 3)
    np.testing.assert_array_equal(P2.astype(np.float32), P)
    np.testing.assert_array_equal(C2, C)
    moving = rng.random(1234) < 0.3
    v = ply.read_ply_vertices(ply.write_ply(tmp_path / "m.ply", P, C, moving))
    np.testing.assert_array_equal(v["moving"], moving)
    assert "moving" not in ply.read_ply_vertices(path)
    try:
        import open3d as o3d
    except Exception:  # optional peer
        return
    pc = o3d.io.read_point_cloud(str(path))
    assert len(pc.points) == 1234
    np.testing.assert_allclose(np.asarray(pc.points), P, atol=1e-6)
    np.testing.assert_allclose(np.asarray(pc.colors) * 255, C, atol=0.51)


def test_ply_ascii_and_errors(tmp_path):
    p = tmp_path / "a.ply"
    p.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                 "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
                 "end_header\n0 1 2 255 0 0\n3 4 5 0 0 255\n")
    P, C = ply.read_ply(p)
    np.testing.assert_array_equal(P, [[0, 1, 2], [3, 4, 5]])
    np.testing.assert_array_equal(C, [[255, 0, 0], [0, 0, 255]])
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"not a ply")
    with pytest.raises(ValueError, match="not a PLY"):
        ply.read_ply(bad)
    empty = ply.write_ply(tmp_path / "e.ply", np.zeros((0, 3)), np.zeros((0, 3), np.uint8))
    assert ply.read_ply(empty)[0].shape == (0, 3)


def test_voxel_downsample():
    # 3 voxels of 10 cm: two points each in two voxels, one in a third; the last voxel also has a
    # moving point, which stays apart
    P = np.array([[0.01, 0.01, 0.01], [0.03, 0.05, 0.02], [0.51, 0.01, 0.01], [0.55, 0.05, 0.02],
                  [1.01, 1.01, 1.01], [1.02, 1.02, 1.02]])
    C = np.array([[0, 0, 0], [100, 200, 50], [10, 10, 10], [20, 20, 20], [255, 255, 255], [0, 0, 0]], np.uint8)
    mv = np.array([0, 0, 0, 0, 0, 1], bool)
    p, c, m = mapping.voxel_downsample(P, C, 0.1, mv)
    assert len(p) == 4 and m.sum() == 1
    k = int(np.argmin(np.linalg.norm(p - [0.02, 0.03, 0.015], axis=1)))
    np.testing.assert_allclose(p[k], [0.02, 0.03, 0.015], atol=1e-6)
    np.testing.assert_array_equal(c[k], [50, 100, 25])
    assert len(mapping.voxel_downsample(P, C, 0.0, mv)[0]) == 6
    # a dense random cloud: count equals the number of occupied voxels
    rng = np.random.default_rng(1)
    Q = rng.uniform(0, 1, size=(20000, 3))
    q, _, _ = mapping.voxel_downsample(Q, np.zeros_like(Q, np.uint8), 0.25)
    assert len(q) == 64


def test_points_land_on_the_walls(seq1_dir):
    """Back-projected room pixels of a 3-frame synthetic sequence with exact poses lie on the room's faces."""
    from jaxvo.synthetic import make_sequence
    from jaxvo.synthetic.scene import ROOM_BOUNDS

    seq = TumSequence(seq1_dir, camera=CAM)
    t, T = read_tum_trajectory(seq1_dir / "groundtruth.txt")
    idx, poses = mapping.match_trajectory(seq.timestamps, t, T)
    assert list(idx) == [0, 1, 2]
    syn = make_sequence("seq1", frames=3, seed=0, camera=CAM)
    room = [k for k, o in enumerate(syn.scene.objects) if o.name == "room"][0]
    n_room = 0
    for i, Twc in zip(idx, poses):
        bgr, dep = seq.read_images(i)
        P, C, (r, c) = mapping.backproject_frame(bgr[..., ::-1], dep / 5000.0, CAM, Twc, max_depth=10.0)
        on = syn.render(int(i)).object_id[r, c] == room
        Q = P[on]
        dist = np.min(np.abs(np.concatenate([Q - ROOM_BOUNDS[:, 0], Q - ROOM_BOUNDS[:, 1]], 1)), axis=1)
        assert np.max(dist) < 0.003, np.max(dist)
        n_room += len(Q)
        np.testing.assert_array_equal(C, bgr[r, c][:, ::-1])
    assert n_room > 1000


def test_build_map_with_masks_and_preview(seq1_dir, tmp_path):
    seq = TumSequence(seq1_dir, camera=CAM)
    t, T = seq.groundtruth
    calls = []
    res = mapping.build_map(seq, t, T, every=2, voxel=0.02, labels="masks", progress=lambda d, n: calls.append((d, n)))
    assert list(res.frames) == [0, 2] and calls == [(1, 2), (2, 2)]
    cl = res.cloud
    assert 0 < len(cl) < res.raw_points and cl.moving.any() and (~cl.moving).any()
    disp = cl.display_colors()
    assert np.all(disp[cl.moving] == mapping.MOVING_COLOUR)
    # the person of seq1 walks at ~2 m in front of the fixed camera, well inside the room
    assert np.all(np.abs(cl.points[cl.moving][:, 0]) < 2.0)
    assert mapping.build_map(seq, t, T, every=1, voxel=0, labels=None).raw_points == \
        len(mapping.build_map(seq, t, T, every=1, voxel=0, labels=None).cloud)
    png = mapping.render_preview(cl.points, disp, tmp_path / "p.png", poses=res.poses)
    assert png.stat().st_size > 5000
    img = mapping.preview_image(cl.points, disp, res.poses, (160, 120))
    assert img.shape == (120, 160, 3) and (img != 255).any()
    with pytest.raises(DatasetError, match="no trajectory pose"):
        mapping.build_map(seq, t + 100.0, T)


def test_moving_mask_leaves_out_pixels_hidden_in_the_current_frame():
    from types import SimpleNamespace
    from jaxvo.pipelines.mapping import moving_mask, outlier_mask
    valid = np.ones((4, 6), bool)
    valid[0, 0] = False
    inlier = np.ones((4, 6), bool)
    inlier[1, :3] = False                      # three outliers ...
    occluded = np.zeros((4, 6), bool)
    occluded[1, 2] = True                      # ... one of them hidden behind something new
    est = SimpleNamespace(valid_mask=valid, inlier_mask=inlier, occluded_mask=occluded)
    assert outlier_mask(est, 6, 4).sum() == 3
    m = moving_mask(est, 6, 4)
    assert m.sum() == 2 and m[1, 0] and m[1, 1] and not m[1, 2]
    static = np.ones((4, 6), bool)
    static[3, 5] = static[0, 0] = False        # the segmentation's dynamic pixels count, valid or not
    m, v = moving_mask(est, 6, 4, static, valid_too=True)
    assert m.sum() == 4 and m[3, 5] and m[0, 0] and v[0, 0]
    # an estimate at half resolution is scaled up, nearest neighbour
    half = SimpleNamespace(valid_mask=valid[:2, :3], inlier_mask=inlier[:2, :3], occluded_mask=occluded[:2, :3])
    assert moving_mask(half, 6, 4).shape == (4, 6)
    # estimates without the field (made by other code) keep all their outliers
    assert moving_mask(SimpleNamespace(valid_mask=valid, inlier_mask=inlier), 6, 4).sum() == 3
