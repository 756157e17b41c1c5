"""The persistent static/dynamic segmentation (jaxvo.tracking.segmentation) and the streaming Odometry.

Scenes are rendered by jaxvo.synthetic (exact depth, exact moving-pixel masks) at
320x240, the map level of a 640x480 camera, with the camera at half resolution:
a walking person (seq2's cylinder) in a textured room while the camera pans.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxvo import geometry
from jaxvo.tracking import segmentation as S
from jaxvo.camera import DEFAULT, Camera
from jaxvo.config import Config, TrackConfig
from jaxvo.estimator import trace_count
from jaxvo.tracking.odometry import Odometry, track
from jaxvo.synthetic import make_sequence

CAM = DEFAULT
MAP_CAM = CAM.at_level(S.MAP_LEVEL)
P = S.SegmentParams()


@pytest.fixture(scope="module")
def seq():
    """seq2 at 10 Hz so that the person moves ~15 cm between frames: frames 0, 3, 6 and 12."""
    s = make_sequence("seq2", frames=16, seed=0, fps=10.0)
    return s, {k: s.render(k) for k in (0, 3, 6, 12)}


def _md(r):
    return np.asarray(S.map_depth(jnp.asarray(r.depth)))


def _mask_md(mask):
    """Full-resolution bool mask -> map level: a map pixel is 'moving' if any of its block is."""
    f = 1 << S.MAP_LEVEL
    h, w = mask.shape
    return mask[: h // f * f, : w // f * f].reshape(h // f, f, w // f, f).any(axis=(1, 3))


def _T(s, view, ref):
    return (geometry.inverse(s.poses[view]) @ s.poses[ref]).astype(np.float32)


def test_vote_flags_vacated_space_and_confirms_the_room(seq):
    s, r = seq
    moving = _mask_md(r[0].moving_mask)
    assert 0.03 < moving.mean() < 0.4
    # 1.2 s later the person has walked off its frame-0 pixels (measured: 0.82 of them voted
    # 'behind', 0.25 % of the room's, at depth edges, and 0.80 of the room 'seen')
    behind, seen = S.vote(jnp.asarray(_md(r[0])), jnp.asarray(_md(r[12])), jnp.asarray(_T(s, 12, 0)), MAP_CAM, P)
    behind, seen = np.asarray(behind), np.asarray(seen)
    assert behind[moving].mean() > 0.7, behind[moving].mean()
    assert behind[~moving].mean() < 0.005
    assert seen[~moving].mean() > 0.7
    assert not (behind & seen).any()


def test_votes_follow_the_transform_direction(seq):
    """The same votes with the inverse transform are wrong: the map is tied to T_view_ref."""
    s, r = seq
    good = np.asarray(S.vote(jnp.asarray(_md(r[0])), jnp.asarray(_md(r[12])), jnp.asarray(_T(s, 12, 0)),
                             MAP_CAM, P)[1])
    bad = np.asarray(S.vote(jnp.asarray(_md(r[0])), jnp.asarray(_md(r[12])), jnp.asarray(_T(s, 0, 12)),
                            MAP_CAM, P)[1])
    assert good.mean() > bad.mean() + 0.1


def _numpy_vote(ref_md, view_md, T, cam, params):
    """The free-space test written out in float64 NumPy, pixel by pixel in vectors."""
    h, w = ref_md.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    Z = ref_md.astype(np.float64)
    P = np.stack([(u - cam.cx) / cam.fx * Z, (v - cam.cy) / cam.fy * Z, Z], -1) @ T[:3, :3].T.astype(np.float64) \
        + T[:3, 3]
    z = P[..., 2]
    zs = np.where(z > 0.1, z, 1.0)
    pu, pv = np.round(cam.fx * P[..., 0] / zs + cam.cx), np.round(cam.fy * P[..., 1] / zs + cam.cy)
    inside = (Z > 0) & (z > 0.1) & (pu >= 0) & (pu <= w - 1) & (pv >= 0) & (pv <= h - 1)
    d = view_md[np.clip(pv, 0, h - 1).astype(int), np.clip(pu, 0, w - 1).astype(int)]
    ok = inside & (d > 0)
    tol = params.margin + params.slope * z * z
    return ok & (d > z + tol), ok & (np.abs(d - z) <= tol)


def test_votes_match_a_numpy_warp_and_add_up_over_valid_views(seq):
    """vote against an independent float64 warp; add_votes sums the views that are valid only."""
    s, r = seq
    ref = _md(r[0])
    views = [_md(r[k]) for k in (3, 6, 12)]
    Ts = [_T(s, k, 0) for k in (3, 6, 12)]
    for view, T in zip(views, Ts):
        behind, seen = (np.asarray(x) for x in S.vote(jnp.asarray(ref), jnp.asarray(view), jnp.asarray(T), MAP_CAM, P))
        nb, ns = _numpy_vote(ref, view, T, MAP_CAM, P)
        # float32 against float64: only pixels at a rounding or tolerance boundary may differ
        assert (behind != nb).mean() < 1e-3 and (seen != ns).mean() < 1e-3
        assert behind.sum() > 50 and seen.sum() > 1000
    L0 = np.where(np.arange(ref.size).reshape(ref.shape) % 7 == 0, 5.5, -1.0).astype(np.float32)
    valid = np.array([True, False, True])
    L = np.asarray(S.add_votes(jnp.asarray(L0), jnp.asarray(ref), jnp.asarray(np.stack(views)), jnp.asarray(np.stack(Ts)),
                               jnp.asarray(valid), MAP_CAM, P))
    want = L0.copy()
    for view, T, ok in zip(views, Ts, valid):
        if ok:
            b, sn = (np.asarray(x) for x in S.vote(jnp.asarray(ref), jnp.asarray(view), jnp.asarray(T), MAP_CAM, P))
            want = want + P.dynamic_vote * b - P.static_vote * sn
    np.testing.assert_array_equal(L, np.clip(want, -P.clip, P.clip))
    assert (L == P.clip).any()


def test_photometric_outliers_at_the_map_level():
    """Block means down to the map level (a map pixel is an outlier when at least half of its
    valid pixels are and at least half of it is valid), repetition up from a coarser estimate."""
    rng = np.random.default_rng(3)
    out, val = rng.random((12, 16)) < 0.4, rng.random((12, 16)) < 0.7
    got = np.asarray(S.photometric_outliers(jnp.asarray(out & val), jnp.asarray(val), (6, 8)))
    o = (out & val).reshape(6, 2, 8, 2).sum(axis=(1, 3))
    v = val.reshape(6, 2, 8, 2).sum(axis=(1, 3))
    np.testing.assert_array_equal(got, (v >= 2) & (2 * o >= v))
    assert 0 < got.sum() < got.size
    coarse = np.asarray(S.photometric_outliers(jnp.asarray(out[:3, :4] & val[:3, :4]), jnp.asarray(val[:3, :4]), (6, 8)))
    np.testing.assert_array_equal(coarse, np.repeat(np.repeat(out[:3, :4] & val[:3, :4], 2, 0), 2, 1))


def test_current_vote_counts_unexplained_appearance_as_motion(seq):
    """An estimate at the true pose from frame 0 to 3 of seq2: free space says nothing yet on the
    person (it is still where it was along 98 % of its rays), but its texture moved. The outliers the
    estimate leaves there vote dynamic (photo_vote) instead of static; the room's vote is unchanged."""
    from jaxvo.estimator.motion import estimate_motion
    s, r = seq
    T = _T(s, 3, 0)
    est = estimate_motion(r[0].frame(), r[3].frame(), CAM, Config(), jax.random.key(0), init=T)
    ref, cur = _md(r[0]), _md(r[3])
    photo = np.asarray(S.photometric_outliers(est.valid_mask & ~est.inlier_mask & ~est.occluded_mask,
                                              est.valid_mask, ref.shape))
    moving = _mask_md(r[0].moving_mask)
    # measured: 0.71 of them on the person, 0.3 % of the room
    assert (photo & moving).sum() > 0.6 * photo.sum() and (photo & ~moving).mean() < 0.01
    L0 = np.full(ref.shape, P.prior, np.float32)
    L = np.asarray(S.add_current_vote(jnp.asarray(L0), jnp.asarray(ref), jnp.asarray(cur), jnp.asarray(T),
                                      jnp.asarray(photo), MAP_CAM, P))
    behind, seen = (np.asarray(x) for x in S.vote(jnp.asarray(ref), jnp.asarray(cur), jnp.asarray(T), MAP_CAM, P))
    want = L0 + P.dynamic_vote * behind + np.where(seen & photo, P.photo_vote, -P.static_vote * seen)
    np.testing.assert_array_equal(L, np.clip(want, -P.clip, P.clip))
    assert (seen & photo & moving).sum() > 100
    # without unexplained pixels it is add_votes with the one view
    L_none = S.add_current_vote(jnp.asarray(L0), jnp.asarray(ref), jnp.asarray(cur), jnp.asarray(T),
                                jnp.zeros(ref.shape, bool), MAP_CAM, P)
    np.testing.assert_array_equal(np.asarray(L_none), np.asarray(S.add_votes(
        jnp.asarray(L0), jnp.asarray(ref), jnp.asarray(cur)[None], jnp.asarray(T)[None], jnp.ones(1, bool), MAP_CAM, P)))


def test_propagate_carries_the_map_with_the_camera(seq):
    """A map that is exactly the person's mask on frame 0, carried onto frame 3 with the true motion,
    lands on the person's pixels of frame 3 that show the same surface (the person moved, so only
    the part of the body seen in both frames carries)."""
    s, r = seq
    m0 = _mask_md(r[0].moving_mask)
    L0 = np.where(m0, 4.0, -4.0).astype(np.float32)
    L3 = np.asarray(S.propagate(jnp.asarray(L0), jnp.asarray(_md(r[0])), jnp.asarray(_md(r[3])),
                                jnp.asarray(_T(s, 0, 3)), MAP_CAM, P))
    room3 = ~_mask_md(r[3].moving_mask) & (_md(r[3]) > 0)
    # the room keeps its static log-odds (scaled by carry) nearly everywhere
    assert np.mean(L3[room3] < 0) > 0.97
    assert np.isclose(np.median(L3[room3]), -4.0 * P.carry)
    # nothing carried is dynamic where frame 3 sees the room
    assert np.mean(L3[room3] > 0) < 0.01


def test_coherent_regions_flag_the_whole_person(seq):
    """Evidence only on a strip along one side of the person (as residuals give along its edges)
    becomes the whole body; the room stays static."""
    s, r = seq
    md = _md(r[0])
    moving = _mask_md(r[0].moving_mask) & (md > 0)
    cols = np.where(moving.any(axis=0))[0]
    strip = moving.copy()
    strip[:, : cols[-1] - (cols[-1] - cols[0]) // 3] = False     # only the person's right third
    L = np.where(strip, 4.0, P.prior).astype(np.float32)
    out = np.asarray(S.coherent_regions(jnp.asarray(L), jnp.asarray(md), MAP_CAM, P))
    flagged = out > 0
    recall = (flagged & moving).sum() / moving.sum()
    false_pos = (flagged & ~moving & (md > 0)).sum() / (~moving & (md > 0)).sum()
    assert strip.sum() < 0.5 * moving.sum()
    assert recall > 0.8, recall
    assert false_pos < 0.05, false_pos


@pytest.fixture(scope="module")
def seq30():
    """seq2 at 30 Hz: the person moves ~20 cm in 4 frames, a few pixels at the motion test's level."""
    s = make_sequence("seq2", frames=5, seed=0, fps=30.0)
    return s, {k: s.render(k) for k in (0, 4)}


def test_motion_regions_flag_the_region_that_moved_and_not_the_room(seq30):
    """The person's regions line up with a view 4 frames earlier only when shifted in the image,
    the room's at the true pose: the test flags most of the person and almost none of the room;
    a view that is the reference itself flags nothing, and motion_gain = inf turns it off."""
    s, r = seq30
    md = jnp.asarray(_md(r[4]))
    labels = S.region_labels(md, MAP_CAM)
    cue_cam = CAM.at_level(S.CUE_LEVEL)
    ref_cue, view_cue = (S.cue_images(jnp.asarray(r[k].intensity), jnp.asarray(r[k].depth)) for k in (4, 0))
    moving = _mask_md(r[4].moving_mask) & (np.asarray(md) > 0)
    room = ~_mask_md(r[4].moving_mask) & (np.asarray(md) > 0)

    def test(view, T, params=P):
        return np.asarray(S.motion_regions(*labels, ref_cue, view, jnp.asarray(T), cue_cam, params)) & (np.asarray(md) > 0)

    flagged = test(view_cue, _T(s, 0, 4))
    assert flagged.shape == md.shape
    assert (flagged & moving).sum() / moving.sum() > 0.9
    assert (flagged & room).sum() / room.sum() < 0.02
    assert not test(ref_cue, np.eye(4, dtype=np.float32)).any()
    assert not test(view_cue, _T(s, 0, 4), P._replace(motion_gain=float("inf"))).any()


@pytest.mark.parametrize("exposure", [lambda i: i + 25.0, lambda i: i * 1.25], ids=["plus25", "times1.25"])
def test_motion_regions_take_an_exposure_change_for_no_motion(seq30, exposure):
    """The view 25 grey levels (or 25 %) brighter, as a camera's auto exposure makes it: the
    room still lines up best in place and stays unflagged, the person is still flagged.
    Without the regions' in-place offset removed, 24 % (45 %) of the room was flagged."""
    s, r = seq30
    md = jnp.asarray(_md(r[4]))
    labels = S.region_labels(md, MAP_CAM)
    ref_cue, (view_int, view_depth) = (S.cue_images(jnp.asarray(r[k].intensity), jnp.asarray(r[k].depth)) for k in (4, 0))
    flagged = np.asarray(S.motion_regions(*labels, ref_cue, (exposure(view_int), view_depth), jnp.asarray(_T(s, 0, 4)),
                                          CAM.at_level(S.CUE_LEVEL), P)) & (np.asarray(md) > 0)
    moving = _mask_md(r[4].moving_mask) & (np.asarray(md) > 0)
    room = ~_mask_md(r[4].moving_mask) & (np.asarray(md) > 0)
    assert (flagged & moving).sum() / moving.sum() > 0.9
    assert (flagged & room).sum() / room.sum() < 0.02


def test_odometry_flags_the_person_with_the_motion_test():
    """At 640x480 the odometry's map takes in the motion test at each new reference: on seq2's
    first 12 frames the person is wholly untrusted from frame 9 on (the view 8 frames back
    exists), while free space and appearance alone leave two thirds of it trusted."""
    s = make_sequence("seq2", frames=12, seed=0)
    rs = [s.render(k) for k in range(12)]

    def recall(params):
        odo = Odometry(CAM, Config(), jax.random.key(0), segment_params=params)
        steps = [odo.add(r.frame()) for r in rs]
        return [(~st.static_mask & rs[st.reference].moving_mask).sum() / rs[st.reference].moving_mask.sum()
                for st in steps[9:]]

    assert min(recall(P)) > 0.9
    assert max(recall(P._replace(motion_gain=float("inf")))) < 0.6


def test_a_reference_without_an_earlier_view_is_tested_against_a_later_frame():
    """Frame 0 has no earlier view for the motion test: until frame 3 the map has no evidence
    on the person; the test against frame 3 (at its estimate) flags part of it for the frames
    estimated after it, and nothing of it without the test (motion_gain = inf). Measured:
    recall 0.47-0.48, false positives 0.5 % of the room."""
    s = make_sequence("seq2", frames=7, seed=0)
    rs = [s.render(k) for k in range(7)]
    moving, room = rs[0].moving_mask, ~rs[0].moving_mask & (rs[0].depth > 0)

    def masks(params):
        odo = Odometry(CAM, Config(), jax.random.key(0), policy=TrackConfig(calm_fraction=0.0, motion_retest=0),
                       segment_params=params)
        steps = [odo.add(r.frame()) for r in rs][1:]
        assert [st.reference for st in steps] == [0] * 6
        return [((~st.static_mask & moving).sum() / moving.sum(), (~st.static_mask & room).sum() / room.sum())
                for st in steps]

    tested = masks(P)
    assert max(r for r, _ in tested[:3]) < 0.05 and min(r for r, _ in tested[3:]) > 0.3, tested
    assert max(f for _, f in tested) < 0.02, tested
    assert max(r for r, _ in masks(P._replace(motion_gain=float("inf")))) < 0.05


def test_the_motion_test_repeated_at_every_frame_flags_what_one_test_half_saw():
    """TrackConfig.motion_retest: frame 0's reference, tested once against frame 3 (at its
    estimate), leaves half the person trusted (the once-only test above); tested again at every
    later frame (the default, 1), the person is flagged almost wholly from the next frame on,
    while the room stays trusted. Measured: recall 0.99, 1.0-1.1 % of the room flagged."""
    s = make_sequence("seq2", frames=7, seed=0)
    rs = [s.render(k) for k in range(7)]
    moving, room = rs[0].moving_mask, ~rs[0].moving_mask & (rs[0].depth > 0)

    def masks(retest):
        odo = Odometry(CAM, Config(), jax.random.key(0), policy=TrackConfig(calm_fraction=0.0, motion_retest=retest))
        steps = [odo.add(r.frame()) for r in rs][1:]
        assert [st.reference for st in steps] == [0] * 6
        return [((~st.static_mask & moving).sum() / moving.sum(), (~st.static_mask & room).sum() / room.sum())
                for st in steps[4:]]   # frames 5 and 6: after the tests at frames 3 and 4

    assert TrackConfig().motion_retest == 1
    every = masks(1)
    assert min(r for r, _ in every) > 0.9 and max(f for _, f in every) < 0.02, every
    assert max(r for r, _ in masks(0)) < 0.6


def test_region_labels_are_the_ones_coherent_regions_decide_on(seq):
    """coherent_regions with the labels passed in gives what it gives computing them itself."""
    s, r = seq
    md = jnp.asarray(_md(r[0]))
    L = jnp.where(jnp.asarray(_mask_md(r[0].moving_mask)), 4.0, P.prior).astype(jnp.float32)
    lab, k = S.region_labels(md, MAP_CAM)
    assert lab.shape == md.shape and lab.dtype == jnp.int32 and int(lab.max()) < k
    np.testing.assert_array_equal(np.asarray(S.coherent_regions(L, md, MAP_CAM, P, labels=(lab, k))),
                                  np.asarray(S.coherent_regions(L, md, MAP_CAM, P)))


def test_reference_map_flags_regions_for_the_trust_but_carries_only_the_evidence(seq):
    """A new reference's region decisions (the moving regions and the coherent ones) raise its
    trust to +2 while it is the reference; the evidence it carries on holds the moving regions
    at ``motion_vote`` only and nothing of what coherence alone flagged, so a region decision
    over a mixed region does not spread into the next reference's regions."""
    s, r = seq
    md = jnp.asarray(_md(r[0]))
    moving = _mask_md(r[0].moving_mask) & (np.asarray(md) > 0)
    cols = np.where(moving.any(axis=0))[0]
    strip = moving.copy()
    strip[:, : cols[-1] - (cols[-1] - cols[0]) // 3] = False
    L = jnp.asarray(np.where(strip, 4.0, P.prior).astype(np.float32))
    labels = S.region_labels(md, MAP_CAM)
    none = jnp.zeros(md.shape, bool)
    evidence, flags = S.reference_map(L, md, labels, none, P)
    np.testing.assert_array_equal(np.asarray(evidence), np.asarray(L))
    np.testing.assert_array_equal(np.asarray(S.flagged(L, flags)), np.asarray(S.coherent_regions(L, md, MAP_CAM, P)))
    assert (np.asarray(flags) & moving).sum() > 0.8 * moving.sum()
    # the motion test's regions: flagged, and carried at motion_vote (over the prior of -1)
    moved = jnp.asarray(moving)
    evidence, flags = S.reference_map(L, md, labels, moved, P)
    ev = np.asarray(evidence)
    np.testing.assert_array_equal(ev[moving & ~strip], P.motion_vote)
    np.testing.assert_array_equal(ev[strip], 4.0)
    np.testing.assert_array_equal(ev[~moving], np.asarray(L)[~moving])
    assert np.asarray(flags)[moving].all()
    assert (np.asarray(S.flagged(evidence, flags))[moving] >= 2.0).all()


def test_upsample_and_weight():
    L = jnp.asarray([[0.0, 10.0], [-10.0, 0.0]])
    w = np.asarray(S.upsample(S.static_weight(L), (5, 4)))
    assert w.shape == (5, 4)
    np.testing.assert_allclose(w[:2, :2], 0.5)
    assert w[0, 3] < 1e-4 and w[3, 0] > 1 - 1e-4 and w[4, 0] == w[3, 0]


@pytest.mark.parametrize("gain", [1.0, 3.0, 7.5])
def test_static_weight_gain_sharpens_without_changing_the_trusted_pixels(gain):
    L = np.linspace(-6.0, 6.0, 241, dtype=np.float32).reshape(1, -1)
    w = np.asarray(S.static_weight(jnp.asarray(L), jnp.float32(gain)))
    # the logistic function written out, in float64
    np.testing.assert_allclose(w, 1.0 / (1.0 + np.exp(gain * L.astype(np.float64))), rtol=2e-6, atol=1e-7)
    np.testing.assert_array_equal(w >= 0.5, L <= 0)
    if gain == 1.0:   # the map's own probability, bit for bit the gain-free weight
        np.testing.assert_array_equal(w, np.asarray(S.static_weight(jnp.asarray(L))))
    else:   # a sharper step: farther from 0.5 wherever the map has a say
        p = np.asarray(S.static_weight(jnp.asarray(L)))
        assert (np.abs(w - 0.5) >= np.abs(p - 0.5) - 1e-7).all()
        assert (np.abs(w - 0.5) > np.abs(p - 0.5))[np.abs(L) > 0.1].all()


def test_static_weight_share_sharpens_only_maps_that_trust_a_minority():
    """With ``share`` the gain applies where the map trusts (L <= 0) under that fraction of its
    pixels, and a map trusting more keeps the probability bit for bit."""
    def logistic(L, g):
        return 1.0 / (1.0 + np.exp(g * L.astype(np.float64)))
    for lo, hi, sharpened in ((-1.0, 3.0, True), (-3.0, 1.0, False)):   # a quarter, three quarters trusted
        L = np.linspace(lo, hi, 400, dtype=np.float32).reshape(20, 20)
        assert ((L <= 0).mean() < 0.5) == sharpened
        w = np.asarray(S.static_weight(jnp.asarray(L), jnp.float32(3.0), jnp.float32(0.5)))
        np.testing.assert_allclose(w, logistic(L, 3.0 if sharpened else 1.0), rtol=2e-6, atol=1e-7)
        if not sharpened:
            np.testing.assert_array_equal(w, np.asarray(S.static_weight(jnp.asarray(L))))
        # a share above every map's trusted fraction: the gain everywhere, as without a share
        np.testing.assert_array_equal(np.asarray(S.static_weight(jnp.asarray(L), jnp.float32(3.0), jnp.float32(1.0))),
                                      np.asarray(S.static_weight(jnp.asarray(L), jnp.float32(3.0))))


def test_trust_gain_weights_the_estimates_and_one_is_the_probability(frames320):
    """TrackConfig.trust_gain reaches the weights every estimate is given where the map trusts
    under ``trust_share`` of its pixels, and 1 gives the map's probability: the StaticMap's trust
    equals static_weight of its evidence at the gain that applies."""
    s, cam, rs = frames320
    frame = rs[0].frame()
    shape = tuple(frame.depth.shape)
    for gain, share, (lo, hi), applied in ((1.0, 1.0, (-3, 3), 1.0), (3.0, 1.0, (-3, 3), 3.0),
                                           (3.0, 0.5, (-1, 3), 3.0), (3.0, 0.5, (-3, 1), 1.0)):
        odo = Odometry(cam, Config(), policy=TrackConfig(trust_gain=gain, trust_share=share))
        odo.add(frame)
        smap = odo.static_map
        L = jnp.asarray(np.linspace(lo, hi, smap.L.size, dtype=np.float32).reshape(smap.L.shape))
        smap.L = L
        want = 1.0 / (1.0 + np.exp(applied * np.asarray(S.flagged(L, smap.flags), np.float64)))
        want = np.repeat(np.repeat(want, 2, 0), 2, 1)[: shape[0], : shape[1]]
        got = np.asarray(smap.trust(shape))
        np.testing.assert_allclose(got, want, rtol=2e-6, atol=1e-7)
        if applied == 1.0:
            np.testing.assert_array_equal(got, np.asarray(S.upsample(S.static_weight(S.flagged(L, smap.flags)), shape)))


# ----------------------------------------------------------------------------- Odometry


@pytest.fixture(scope="module")
def frames320():
    """seq3 (two persons, pan-tilt camera) at 320x240, 24 frames at 30 Hz."""
    cam = CAM.at_level(1)
    s = make_sequence("seq3", frames=24, seed=1, camera=cam)
    rs = [s.render(k) for k in range(len(s))]
    return s, cam, rs


def test_odometry_is_track_and_deterministic(frames320):
    s, cam, rs = frames320
    frames = [r.frame() for r in rs]
    odo = Odometry(cam, Config(), jax.random.key(3))
    steps = [odo.add(f) for f in frames]
    assert steps[0].reference == -1 and steps[0].estimate is None
    tr = track(frames, cam, Config(), jax.random.key(3))
    np.testing.assert_array_equal(odo.result().poses, tr.poses)
    again = track(frames, cam, Config(), jax.random.key(3))
    np.testing.assert_array_equal(again.poses, tr.poses)
    assert np.array_equal(tr.reference, odo.result().reference)
    # references are earlier frames and move along
    assert np.all(tr.reference < np.arange(1, len(frames)))
    assert len(set(tr.reference.tolist())) >= 3


def test_odometry_compiles_once(frames320):
    s, cam, rs = frames320
    frames = [r.frame() for r in rs]

    def run(frames, key):
        odo = Odometry(cam, Config(), key)
        for f in frames:
            odo.add(f)
        # the programs compiled ahead in its thread: counted once it is done (under load it may
        # still run after the last frame)
        odo.static_map.compiling.join()

    # warm: every function compiled, the new reference's map with few views and with all of
    # them included (_VIEWS); what earlier tests in this process compiled must not matter
    run(frames, jax.random.key(0))
    n = trace_count()
    sizes = _compiled()
    run(frames, jax.random.key(1))
    assert trace_count() == n
    assert _compiled() == sizes


def _compiled():
    """What grows when a map program is compiled again: its jit's cache, its traces, and the
    exported programs (jaxvo.runtime.aot) read or exported in this process."""
    from jaxvo.runtime import aot
    from jaxvo.tracking import static_map as M
    programs = [M._update_map, M._new_reference_map, M._later_motion_test]
    return ([f._cache_size() for f in [M._map_inputs, M._trust, M._trust_ratios, M._unexplained]]
            + [(p.jitted._cache_size(), p.traces) for p in programs] + [aot.stats()])


def test_odometry_segments_the_persons_and_tracks(frames320):
    """Default odometry on seq3: the static masks it used are the persons, the trajectory is accurate."""
    s, cam, rs = frames320
    frames = [r.frame() for r in rs]
    masks = {}

    def keep(step):
        masks[step.frame] = (step.reference, step.static_mask)

    tr = track(frames, cam, Config(), jax.random.key(0), callback=keep)
    tp = fp = fn = 0
    for j, (ref, static) in masks.items():
        if j < 12:
            continue   # the map needs a few references' worth of views first
        moving = rs[ref].moving_mask & (rs[ref].depth > 0)
        dyn = ~static & (rs[ref].depth > 0)
        tp += (dyn & moving).sum()
        fp += (dyn & ~moving).sum()
        fn += (~dyn & moving).sum()
    precision, recall = tp / max(tp + fp, 1), tp / max(tp + fn, 1)
    # measured: precision 0.88, recall 0.54 (0.8 s of slow walkers: little space has been seen
    # vacated yet; the recall target of 0.8 is not met here)
    assert precision > 0.75 and recall > 0.15, (precision, recall)
    E = geometry.inverse(s.poses[-1]) @ s.poses[0] @ geometry.inverse(tr.poses[0]) @ tr.poses[-1]
    assert np.linalg.norm(E[:3, 3]) < 0.02 and np.degrees(geometry.rotation_angle(E[:3, :3])) < 0.5


def test_calm_scenes_go_frame_to_frame_and_persons_bring_keyframes(frames320):
    """While the map sees nothing move, every frame is the next reference; once it has seen
    the persons move the keyframes take over (TrackConfig.calm_fraction)."""
    s, cam, rs = frames320
    static = make_sequence("seq0", frames=6, seed=1, camera=cam)
    calm = track([static.render(k).frame() for k in range(6)], cam, Config(), jax.random.key(0))
    assert calm.reference.tolist() == [0, 1, 2, 3, 4]
    busy = track([r.frame() for r in rs], cam, Config(), jax.random.key(0))
    lag = np.arange(1, len(rs)) - busy.reference
    assert (lag[12:] > 1).mean() > 0.5, busy.reference.tolist()
    never = track([static.render(k).frame() for k in range(6)], cam, Config(), jax.random.key(0),
                  policy=TrackConfig(calm_fraction=0.0))
    assert never.reference.tolist() == [0, 0, 0, 0, 0]


def test_calm_estimates_stop_at_the_calm_min_width_level(frames320, monkeypatch):
    """With the segmentation and RANSAC, the estimates without static weights (the calm mode's)
    stop at the coarsest level at least TrackConfig.calm_min_width pixels wide (320: level 1 of
    640x480 frames, level 0 of 320x240 ones), the weighted ones at Config.finest_level; None (the
    default) keeps every estimate at the config's level, a coarser config's level wins, and classic or unsegmented
    trackings are untouched. On a static scene the half-resolution chain stays about as accurate as
    the full one."""
    from jaxvo.tracking import odometry
    s, cam, rs = frames320
    calls = []
    estimate = odometry.estimate_motion

    def spy(ref, cur, camera, config, key, **kw):
        calls.append((kw.get("weights") is None, config.finest_level))
        return estimate(ref, cur, camera, config, key, **kw)

    monkeypatch.setattr(odometry, "estimate_motion", spy)
    static = make_sequence("seq0", frames=6, seed=1, camera=cam)
    frames = [static.render(k).frame() for k in range(6)]

    def final_error(policy):
        calls.clear()
        tr = track(frames, cam, Config(), jax.random.key(0), policy=policy)
        E = geometry.inverse(static.poses[-1]) @ static.poses[0] @ geometry.inverse(tr.poses[0]) @ tr.poses[-1]
        return float(np.linalg.norm(E[:3, 3])), list(calls)

    half, half_calls = final_error(TrackConfig(calm_min_width=160))     # 320x240 frames: level 1
    full, full_calls = final_error(TrackConfig())                      # None: full resolution
    assert (True, 1) in half_calls and all(level == (1 if calm else 0) for calm, level in half_calls), half_calls
    assert all(level == 0 for _, level in full_calls) and (True, 0) in full_calls, full_calls
    assert half < 0.005 and full < 0.005 and half < full + 0.002, (half, full)
    calls.clear()
    track([r.frame() for r in rs[:14]], cam, Config(), jax.random.key(0), policy=TrackConfig(calm_min_width=160))
    assert {(True, 1), (False, 0)} <= set(calls), calls                # the busy scene has both kinds
    assert TrackConfig().calm_min_width is None
    half_res = Odometry(CAM, policy=TrackConfig(calm_min_width=320))    # 640x480: level 1
    assert half_res._calm_config.finest_level == 1 and half_res._window_calm_config.finest_level == 1
    assert half_res.estimate_config.finest_level == 0
    # 320x240: three levels, 0-2
    assert Odometry(cam, Config(finest_level=2), policy=TrackConfig(calm_min_width=160))._calm_config.finest_level == 2
    assert Odometry(cam, policy=TrackConfig(calm_min_width=1))._calm_config.finest_level == 2
    for odo in (Odometry(CAM), Odometry(cam, policy=TrackConfig(calm_min_width=320)),
                Odometry(CAM, Config(method="classic"), policy=TrackConfig(calm_min_width=320)),
                Odometry(CAM, policy=TrackConfig.keyframes(calm_min_width=320))):
        assert odo._calm_config is odo.estimate_config and odo._window_calm_config is odo._window_config
    with pytest.raises(ValueError, match="calm_min_width"):
        TrackConfig(calm_min_width=0).validate()


def test_frame_to_frame_policy_has_no_segmentation(frames320):
    s, cam, rs = frames320
    steps = []
    track([r.frame() for r in rs[:4]], cam, Config(method="classic"), policy=TrackConfig.frame_to_frame(),
          callback=steps.append)
    assert [st.reference for st in steps] == [0, 1, 2]
    assert all(st.static_mask is None for st in steps)


@pytest.mark.parametrize("exported", [False, True])
def test_map_programs_compiled_ahead_are_the_ones_called(caplog, tmp_path, exported, monkeypatch, aot_restored):
    """The segmentation's programs compiled in the background from the first frame have the
    signatures of the later calls: those calls compile nothing (a mismatch, e.g. a dtype or a
    sharding, would compile every program twice, once for nothing). Through the exported
    programs (jaxvo.runtime.aot, as the CLI runs them: the estimator and the map programs), whose
    outputs are committed to the device, the estimator compiles once although its weights are
    the map's on some frames and none on others, and the map's programs are each exported once,
    by the thread. The motion tests are let run at this small size, so that the first
    reference's later test is among the calls."""
    from jaxvo.runtime import aot
    from jaxvo.tracking import static_map as M
    monkeypatch.setattr(M, "_CUE_MIN_WIDTH", 0)
    later = []

    class Spy:   # counts the calls (the background thread compiles the module's program)
        def __init__(self, fn):
            self.fn = fn

        def __call__(self, *args):
            later.append(1)
            return self.fn(*args)

    monkeypatch.setattr(M.StaticMap, "later_motion_test_program", staticmethod(Spy(M._later_motion_test)))
    cam = Camera(150.0, 150.0, 95.5, 71.5, 192, 144)   # an image size no other test compiles for
    s = make_sequence("seq3", frames=8, seed=1, camera=cam)
    frames = [s.render(k).frame() for k in range(len(s))]
    # classic: the quickest estimator to compile; the map's programs are the same for every method
    odo = Odometry(cam, Config(method="classic"), jax.random.key(0))
    calm = []
    programs = (M._update_map, M._new_reference_map, M._later_motion_test)
    try:
        aot.enable(tmp_path / "exported" if exported else None)
        before = [p.traces for p in programs]
        odo.add(frames[0])
        odo.static_map.compiling.join()
        traces = [p.traces for p in programs]
        names = ("_trust_ratios", "_unexplained") + sum(((p.name, p.fn.__name__) for p in programs), ())
        with jax.log_compiles(True), caplog.at_level("DEBUG", logger="jax"):
            steps = []
            for f in frames[1:]:
                calm.append(odo._calm)     # the next estimate runs without the map's weights
                steps.append(odo.add(f))
    finally:
        aot.enable(None)
    # the thread traced each once (jit, or export into the fresh folder); the calls none again
    assert [a - b for a, b in zip(traces, before)] == [1, 1, 1] and [p.traces for p in programs] == traces
    if exported:
        files = [f.name.split("-")[0] for f in (tmp_path / "exported").glob("*.jaxexport")]
        assert [files.count(p.name) for p in programs] == [1, 1, 1], files
    compiled = [r.getMessage() for r in caplog.records if "Finished XLA compilation" in r.getMessage()]
    estimator = [m for m in compiled if "_estimate" in m]   # jit(_estimate_pyramids) or jit(call_estimate)
    assert len(estimator) == 1, estimator                                # and the log is captured
    assert not [m for m in compiled if any(n in m for n in names)], compiled
    # the map's weights and its static mask: one placement of the map in every call (aot.placed)
    assert [sum(f"jit({n})" in m for m in compiled) for n in ("_trust", "_trusted")] == [1, 1], compiled
    # nor the stack of a new reference map's few (4) views (12 views may compile later)
    md_shape = "float32[%d,%d]" % odo.static_map.L.shape
    assert not [r.getMessage() for r in caplog.records
                if r.getMessage().startswith("Compiling jit(stack)") and r.getMessage().count(md_shape) == 4]
    assert len({st.reference for st in steps}) >= 2                     # a new reference map was made
    assert True in calm and False in calm, calm
    assert later, "the later motion test did not run"
