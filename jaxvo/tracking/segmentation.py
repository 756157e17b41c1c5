"""A static / dynamic segmentation of the reference frame that lives across frames.

Between consecutive frames people move a few centimetres, under any residual
threshold, so a per-pair inlier test cannot tell them from the static scene.
What does tell them apart is *free space*: if another frame, whose pose relative
to the reference is known, looked along the ray of a reference pixel and saw a
surface clearly *behind* that pixel's 3-D point, the point was not there when
that frame was taken: it belongs to something that moves (the reasoning of
background-model methods such as BaMVO and ReFusion). A frame that sees the
point where it is gives weak evidence that it is static; a frame that sees
something in front of it says nothing (occlusion).

The map is a per-pixel log-odds ``L`` that the reference pixel is *dynamic*, at
pyramid level 1 (half resolution). It is

* started for a new reference from the previous reference's map, carried over
  with the estimated motion (:func:`propagate`), plus the free-space votes of
  earlier and later frames kept in a short history (:func:`vote`);
* updated after every estimate against that reference with the current frame's
  vote (the sign of the depth residual at the estimated pose: this is how each
  estimate's residuals feed the map);
* tested for motion per region (:func:`motion_regions`) at each new reference: a
  region that lines up with a view up to 8 frames back only when shifted in the
  image moved between the two, whatever its texture and whether or not it
  vacated space (the free-space votes see a person walking along the line of
  sight, or sideways in front of a near wall, only along a thin strip); a reference with no
  such view at least 3 frames back (the first ones) is tested once more against the frame 3
  frames after it (:class:`jaxvo.tracking.odometry.Odometry`);
* made coherent per region (:func:`coherent_flags`): the reference's 3-D points
  are grouped by k-means (as Joint-VO-SF / StaticFusion do), and a group whose
  pixels are mostly dynamic is flagged as a whole, so a person is flagged as a
  body, not only along the edges where residuals are large.

The region decisions (moving and coherent regions) raise the reference's trust
while it is the reference; what is carried on is the per-pixel evidence, with
the moving regions at ``motion_vote`` (+2 by default; :func:`reference_map` says why).

The trust passed to :func:`jaxvo.estimator.motion.estimate_motion` (``weights=``) is
``static_weight(flagged(L, flags), gain, share)``, sigmoid(-L) with L raised by the flags, sharpened
to sigmoid(-gain * L) where the map trusts under ``share`` of its pixels (``TrackConfig.trust_gain``,
``trust_share``): RANSAC samples pixels of weight >= 0.5, scoring and refinement weigh by it.

Everything is pure JAX with static shapes; the host-side loop that owns the
state is :class:`jaxvo.tracking.odometry.Odometry`.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxvo.camera import Camera, backproject_planes
from jaxvo.estimator.pyramid import block_mean, downsample, sanitize_depth
from jaxvo.estimator.residuals import sample_bilinear, sample_nearest

__all__ = ["SegmentParams", "MAP_LEVEL", "CUE_LEVEL", "map_depth", "cue_images", "vote", "add_votes",
           "photometric_outliers", "add_current_vote", "propagate", "region_labels", "motion_regions",
           "coherent_regions", "coherent_flags", "reference_map", "flagged", "static_weight", "upsample"]

# the pyramid level the map lives on: half resolution is ample for person-sized regions
# and costs a quarter of full resolution (docs/decisions/cpu-kernels.md)
MAP_LEVEL = 1


class SegmentParams(NamedTuple):
    """Numeric parameters of the segmentation (pytree leaves, so they can be swept).

    margin, slope: a surface counts as seen *behind* a point (or at it) when the depths
      differ by more than (less than) ``margin + slope * z^2`` metres: the Kinect-class
      depth noise grows with z^2, and 0.1 m is over the few-cm motion of a person
      between frames, so only clearly vacated space votes.
    dynamic_vote: log-odds added for each frame that saw behind the point.
    static_vote: log-odds removed for each frame that saw the point where it is.
    prior: log-odds of a pixel no frame has voted on (negative: static unless shown otherwise).
    clip: |L| is kept below this, so that the map can change its mind in a few votes.
    carry: fraction of the log-odds a pixel keeps when the map moves to the next reference.
    region_ratio: a region whose valid pixels are dynamic (L > 0) in at least this
      fraction is flagged as a whole.
    photo_vote: log-odds added, instead of removing ``static_vote``, for each estimate whose
      frame saw the point at its depth but did not explain it (an outlier not hidden in that
      frame): the appearance of a surface moving within itself (:func:`add_current_vote`).

    static_vote and region_ratio are set for the moving mask's recall on sequences with exact
    masks, leaving the trajectory as it is; photo_vote is the middle of the range that helps
    crowds without flagging static scene (docs/decisions/segmentation.md).

    motion_gain, motion_shift: a region is moving (:func:`motion_regions`) when shifting its
      warped pixels in the image of an earlier view by at least ``motion_shift`` pixels (at
      :data:`CUE_LEVEL`) lowers its mean residual cost (truncated luminance / 30 plus truncated
      depth, each in [0, 1]) by more than ``motion_gain``; ``inf`` turns the test off
      (docs/decisions/later-motion-test.md).
    motion_vote: the log-odds (at least) that a region the motion test flags keeps in the
      evidence carried to later references (:func:`reference_map`; the reference's own trust
      has it at +2 in any case). 2 carries the test's decision as strongly as the reference
      trusts it; lower values trade the real crowd's accuracy for the synthetic persons' masks
      (docs/decisions/later-motion-test.md).
    """
    margin: float = 0.1
    slope: float = 0.03
    dynamic_vote: float = 2.0
    static_vote: float = 0.25
    prior: float = -1.0
    clip: float = 6.0
    carry: float = 0.8
    region_ratio: float = 0.2
    photo_vote: float = 0.5
    motion_gain: float = 0.1
    motion_shift: float = 2.0
    motion_vote: float = 2.0


def map_depth(depth, max_depth=4.0):
    """(H, W) metres -> the map level's depth (valid-only 2x2 means, :data:`MAP_LEVEL` times)."""
    d = sanitize_depth(depth, max_depth)
    i = jnp.zeros_like(d)
    for _ in range(MAP_LEVEL):
        i, d = downsample(i, d)
    return d


# the motion test's level (quarter resolution: one 160x120 pass per shift) and its shifts:
# -6..6 pixels in steps of 2 in each direction, 49 in all. A person walking at 1-2 cm per
# frame, 1.5-3 m away, moves 1-3 pixels a frame here, so 8 frames apart it has moved past the
# search's first step while a right pose leaves the static scene within a pixel.
CUE_LEVEL = 2
_SHIFTS = tuple((a, b) for a in range(-6, 7, 2) for b in range(-6, 7, 2))
# every other pixel of that level in each direction: a region's mean cost is as telling from a
# quarter of its pixels, at a quarter of the gathers
_CUE_STRIDE = 2


def cue_images(intensity, depth, max_depth=4.0):
    """(H, W) intensity (0-255) and depth (m) -> both at :data:`CUE_LEVEL` (2x2 means; depth
    over its valid pixels), the inputs of :func:`motion_regions`."""
    i, d = intensity, sanitize_depth(depth, max_depth)
    for _ in range(CUE_LEVEL):
        i, d = downsample(i, d)
    return i, d


def _points(depth, camera: Camera):
    """The 3-D points of a depth image as three (h, w) arrays X, Y, Z (camera frame, metres).

    Kept as separate planes on purpose: XLA on CPU runs the element-wise warps below several
    times slower on interleaved (h * w, 3) points (docs/decisions/cpu-kernels.md).
    """
    h, w = depth.shape
    v = jnp.arange(h, dtype=jnp.float32)[:, None]
    u = jnp.arange(w, dtype=jnp.float32)[None, :]
    return backproject_planes(camera, u, v, depth)


def _projected(points, T_view_ref, camera: Camera):
    """3-D points (X, Y, Z planes, reference camera) moved into a view and projected:
    (u, v, z) planes, float pixel coordinates and depth in the view (z <= 0.1 m projects as if at 1 m)."""
    X, Y, Z = points
    T = T_view_ref
    x = T[0, 0] * X + T[0, 1] * Y + T[0, 2] * Z + T[0, 3]
    y = T[1, 0] * X + T[1, 1] * Y + T[1, 2] * Z + T[1, 3]
    z = T[2, 0] * X + T[2, 1] * Y + T[2, 2] * Z + T[2, 3]
    zs = jnp.where(z > 0.1, z, 1.0)
    return camera.fx * x / zs + camera.cx, camera.fy * y / zs + camera.cy, z


def _transfer(ref_depth, T_view_ref, camera: Camera):
    """Reference pixels moved into a view: (z in the view, pixel index (flat), inside (bool)), each (h, w)."""
    h, w = ref_depth.shape
    u, v, z = _projected(_points(ref_depth, camera), T_view_ref, camera)
    u, v = jnp.round(u), jnp.round(v)
    inside = (ref_depth > 0) & (z > 0.1) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    idx = jnp.clip(v, 0, h - 1).astype(jnp.int32) * w + jnp.clip(u, 0, w - 1).astype(jnp.int32)
    return z, idx, inside


def _at(image, idx):
    """image (h, w) read at flat pixel indices idx (any shape, already inside the image)."""
    return jnp.take(image.reshape(-1), idx, mode="clip")


def vote(ref_depth, view_depth, T_view_ref, camera: Camera, params: SegmentParams):
    """One view's evidence on each reference pixel, at the map level.

    ref_depth, view_depth: (h, w) metres (0 = invalid). T_view_ref: (4, 4) maps reference-camera
    points into the view's camera. camera: intrinsics at the map level.
    Returns (behind, seen): (h, w) bool each. behind: the view saw a surface farther than the
    point along its ray (the point was absent: dynamic evidence). seen: it saw the point where
    it is (static evidence). Neither: outside the view, no depth there, or occluded.
    """
    z, idx, inside = _transfer(ref_depth, T_view_ref, camera)
    d = _at(view_depth, idx)
    ok = inside & (d > 0)
    tol = params.margin + params.slope * z * z
    return ok & (d > z + tol), ok & (jnp.abs(d - z) <= tol)


def add_votes(L, ref_depth, view_depths, T_views_ref, valid, camera: Camera, params: SegmentParams):
    """Add the votes of M views to the dynamic log-odds L (h, w).

    view_depths: (M, h, w); T_views_ref: (M, 4, 4); valid: (M,) bool (False = padding / no pose).
    """
    # one element-wise pass per view, summed as it goes: a vmap over the views and a sum over
    # the view axis is slower on the CPU (docs/decisions/cpu-kernels.md)
    delta = jnp.zeros_like(L)
    for k in range(view_depths.shape[0]):
        behind, seen = vote(ref_depth, view_depths[k], T_views_ref[k], camera, params)
        delta = delta + _vote_delta(valid[k] & behind, valid[k] & seen, params)
    return jnp.clip(L + delta, -params.clip, params.clip)


def _vote_delta(behind, seen, params: SegmentParams, unexplained=False):
    """One view's change of the log-odds: +``dynamic_vote`` where it saw behind the point; where it
    saw the point at its depth, -``static_vote``, or +``photo_vote`` where the estimate of that
    view did not explain it (``unexplained``)."""
    return (jnp.where(behind, params.dynamic_vote, 0.0)
            + jnp.where(seen & unexplained, params.photo_vote, jnp.where(seen, -params.static_vote, 0.0)))


def photometric_outliers(outlier, valid, shape):
    """An estimate's outliers -> (h, w) bool at the map level (``shape``): a map pixel at least
    half of whose pixels are valid, and at least half of those outliers.

    outlier, valid: (H', W') bool at the estimate's finest level (2x2 block means down to the
    map level, or pixel repetition up to it when the estimate stopped at a coarser level)."""
    o, v = outlier.astype(jnp.float32), valid.astype(jnp.float32)
    while o.shape[0] >= 2 * shape[0]:
        o, v = block_mean(o), block_mean(v)
    if o.shape != tuple(shape):
        f = max(1, shape[0] // o.shape[0])
        o, v = upsample(o, shape, f), upsample(v, shape, f)
    return (v >= 0.5) & (o >= 0.5 * v)


def add_current_vote(L, ref_depth, cur_depth, T_cur_ref, photo, camera: Camera, params: SegmentParams):
    """Add the vote of the frame just estimated against the reference to L (h, w).

    Free space as in :func:`vote` (cur_depth: the frame's map-level depth, T_cur_ref its
    estimated pose), except where the frame sees the point at its depth but the estimate
    did not explain it (``photo``: (h, w) bool, :func:`photometric_outliers`): there
    ``photo_vote`` goes towards dynamic instead of the static vote. A surface that moves
    within itself (a person walking sideways, a torso turning) keeps its depth along most
    rays, so free space flags only the strip it vacates; its texture does not stay put."""
    behind, seen = vote(ref_depth, cur_depth, T_cur_ref, camera, params)
    return jnp.clip(L + _vote_delta(behind, seen, params, photo), -params.clip, params.clip)


def propagate(L_old, old_depth, new_depth, T_old_new, camera: Camera, params: SegmentParams):
    """Carry the map of the old reference onto a new one.

    Each new-reference pixel is moved into the old reference's camera (T_old_new maps
    new-reference points into it) and takes the old log-odds there, scaled by ``carry``,
    if the old reference saw the same surface (depths agree within the margin); other
    pixels start at the prior.
    """
    z, idx, inside = _transfer(new_depth, T_old_new, camera)
    d = _at(old_depth, idx)
    same = inside & (d > 0) & (jnp.abs(d - z) <= params.margin + params.slope * z * z)
    return jnp.where(same, params.carry * _at(L_old, idx), params.prior)


def region_labels(depth, camera: Camera, clusters: int = 24, iterations: int = 8, stride: int = 4):
    """The regions of a depth image: k-means on its 3-D points.

    The points of every ``stride``-th pixel are clustered (Lloyd's algorithm, ``clusters``
    centres started on a regular grid of the image, ``iterations`` rounds, deterministic);
    every pixel then joins its nearest centre. Clustering is in 3-D, so a person a metre in
    front of a wall is a region of its own (as Joint-VO-SF / StaticFusion group the scene).
    Returns (labels (h, w) int32 in [0, k), k): invalid pixels get a label too; callers mask them.
    """
    h, w = depth.shape
    X, Y, Z = _points(depth, camera)
    sub = tuple(c[::stride, ::stride].reshape(-1) for c in (X, Y, Z))
    sub_ok = (depth[::stride, ::stride] > 0).reshape(-1)
    # grid initialisation: centres at the points of a coarse pixel grid (deterministic, spread out)
    gh = max(1, int(round((clusters * h / w) ** 0.5)))
    gw = max(1, clusters // gh)
    k = gh * gw
    gv = ((jnp.arange(gh) + 0.5) * h / gh).astype(jnp.int32)
    gu = ((jnp.arange(gw) + 0.5) * w / gw).astype(jnp.int32)
    C0 = jnp.stack([c[gv[:, None], gu[None, :]].reshape(k) for c in (X, Y, Z)], -1)

    def assign(points, C):
        # nearest centre by |c|^2 - 2 p.c (|p|^2 is the same for every centre), one running
        # minimum per centre: element-wise passes that XLA fuses into one loop. An argmin over
        # an (N, k) distance array is most of a new reference's map update on the CPU
        # (docs/decisions/cpu-kernels.md).
        x, y, z = points
        cc = jnp.sum(C * C, -1)
        best = jnp.full(x.shape, jnp.inf, x.dtype)
        label = jnp.zeros(x.shape, jnp.int32)
        for c in range(k):
            d = cc[c] - 2.0 * (x * C[c, 0] + y * C[c, 1] + z * C[c, 2])
            closer = d < best     # strict: ties go to the first centre, as argmin does
            best = jnp.where(closer, d, best)
            label = jnp.where(closer, c, label)
        return label

    sub_w = sub_ok.astype(jnp.float32)
    sub_P = jnp.stack(sub, -1) * sub_w[:, None]

    def step(C, _):
        a = assign(sub, C)
        n = jax.ops.segment_sum(sub_w, a, num_segments=k)
        mean = jax.ops.segment_sum(sub_P, a, num_segments=k) / jnp.maximum(n, 1.0)[:, None]
        return jnp.where(n[:, None] > 0, mean, C), None

    C, _ = jax.lax.scan(step, C0, None, length=iterations)
    return assign((X, Y, Z), C), k


def motion_regions(labels, k: int, ref_cue, view_cue, T_view_ref, camera: Camera, params: SegmentParams):
    """Regions of the reference that moved between an earlier view and the reference.

    Free space sees a person only where it vacated space, and a surface moving within itself
    keeps its depth along most rays; but the region as a whole lines up with the view only
    when shifted in the image. Each region's pixels are warped into the view at the
    estimated pose and then shifted by each of :data:`_SHIFTS`; a region whose mean residual
    cost (truncated luminance / 30 plus depth truncated at 0.05 + 0.015 z^2 m; pixels hidden
    by something in front in the view, outside it or without depth do not count; every other
    pixel of the level) falls by more than ``params.motion_gain`` at its best shift, and that
    shift is at least ``params.motion_shift`` pixels long, is moving. The depth truncation
    grows with z^2, as the sensor's noise does: a flat one flags a floor seen at a grazing
    angle, whose depth changes fast along the image. Each region's mean luminance residual in
    place (the zero shift) is taken off its residuals at every shift, so that a change of
    exposure between the view and the reference does not let a shift onto brighter or darker
    surroundings win; per region, because exposure shifts bright and dark surfaces by
    different amounts, and once per region rather than per shift, since a shift's own offset
    also lets static low-texture surfaces line up better when shifted
    (docs/decisions/later-motion-test.md).

    labels, k: :func:`region_labels` of the reference at the map level (h, w).
    ref_cue, view_cue: (intensity, depth) at :data:`CUE_LEVEL` (:func:`cue_images`), (h/2, w/2).
    T_view_ref: (4, 4) maps reference points into the view. camera: at :data:`CUE_LEVEL`.
    Returns (h, w) bool at the map level: the pixels of the moving regions.
    """
    ref_int, ref_depth = ref_cue
    view_int, view_depth = view_cue
    hc, wc = ref_depth.shape
    st = _CUE_STRIDE
    lab = labels[: 2 * hc: 2, : 2 * wc: 2][::st, ::st].reshape(-1)
    u0, v0, z = (c.reshape(-1) for c in _projected(tuple(c[::st, ::st] for c in _points(ref_depth, camera)),
                                                    T_view_ref, camera))
    ref_int, ref_depth = ref_int[::st, ::st], ref_depth[::st, ::st]
    shifts = jnp.asarray(_SHIFTS, jnp.float32)                       # (S, 2)
    u = (u0[None, :] + shifts[:, :1]).reshape(-1)
    v = (v0[None, :] + shifts[:, 1:]).reshape(-1)
    inside = (u >= 0) & (u <= wc - 1) & (v >= 0) & (v <= hc - 1)
    i_view = sample_bilinear(view_int[..., None], u, v)[:, 0]
    d_view = sample_nearest(view_depth, u, v)
    n_s = len(_SHIFTS)
    zz = jnp.tile(z, n_s)
    hidden = d_view < zz - (0.05 + 0.02 * zz * zz)
    ok = inside & (d_view > 0) & ~hidden & jnp.tile((ref_depth.reshape(-1) > 0) & (z > 0.1), n_s)
    tol = 0.05 + 0.015 * zz * zz
    # per shift and region sums as products with the regions' one-hot matrix: a scatter-add
    # of the 49 x 19,200 values took most of the test's time on the CPU
    onehot = (lab[:, None] == jnp.arange(k)[None, :]).astype(jnp.float32)        # (N, k)
    count = ok.astype(jnp.float32).reshape(n_s, -1) @ onehot                    # (S, k)
    zero = _SHIFTS.index((0, 0))
    residual = (i_view - jnp.tile(ref_int.reshape(-1), n_s)).reshape(n_s, -1)
    # a region's mean luminance change in place is exposure (or a lamp), not motion: removed
    # at every shift, it no longer lets a shift onto brighter or darker surroundings win
    offset = (jnp.where(ok.reshape(n_s, -1)[zero], residual[zero], 0.0) @ onehot) / jnp.maximum(count[zero], 1.0)
    residual = (residual - offset[lab][None, :]).reshape(-1)
    cost = (jnp.minimum(jnp.abs(residual), 30.0) / 30.0
            + jnp.minimum(jnp.abs(d_view - zz), tol) / tol)
    total = jnp.where(ok, cost, 0.0).reshape(n_s, -1) @ onehot
    mean = jnp.where(count > 0, total / jnp.maximum(count, 1.0), jnp.inf)
    best = jnp.argmin(mean, axis=0)
    gain = mean[zero] - jnp.min(mean, axis=0)
    length = jnp.linalg.norm(shifts[best], axis=-1)
    moving = (count[zero] >= 10) & (gain > params.motion_gain) & (length >= params.motion_shift)
    return moving[labels]


def coherent_regions(L, depth, camera: Camera, params: SegmentParams, clusters: int = 24, iterations: int = 8,
                     stride: int = 4, labels=None):
    """Flag whole regions: a region (:func:`region_labels`) with at least ``region_ratio`` of
    its valid pixels dynamic (L > 0) is raised to at least +2 (dynamic) everywhere
    (:func:`coherent_flags` says which).

    labels: ``(labels, k)`` of :func:`region_labels` where the caller has them already.
    """
    return flagged(L, coherent_flags(L, depth, camera, params, clusters, iterations, stride, labels))


def coherent_flags(L, depth, camera: Camera, params: SegmentParams, clusters: int = 24, iterations: int = 8,
                   stride: int = 4, labels=None):
    """(h, w) bool: the valid pixels of the regions (:func:`region_labels`) with at least
    ``region_ratio`` of their valid pixels dynamic (L > 0).

    labels: ``(labels, k)`` of :func:`region_labels` where the caller has them already.
    """
    lab, k = region_labels(depth, camera, clusters, iterations, stride) if labels is None else labels
    flat = lab.reshape(-1)
    valid = depth.reshape(-1) > 0

    def counts(values):
        return jax.ops.segment_sum(values, flat, num_segments=k)

    dyn = (L.reshape(-1) > 0) & valid
    frac = counts(dyn.astype(jnp.float32)) / jnp.maximum(counts(valid.astype(jnp.float32)), 1.0)
    return ((frac >= params.region_ratio)[flat] & valid).reshape(depth.shape)


def reference_map(L, depth, labels, moved, params: SegmentParams):
    """A new reference's evidence and its region flags, from its log-odds ``L`` (h, w) after
    propagation and the views' votes, its map-level ``depth``, its ``labels``
    (:func:`region_labels`) and the regions the motion test found ``moved`` ((h, w) bool).

    Returns (evidence, flags). flags ((h, w) bool): the moving regions and the coherent ones
    (:func:`coherent_flags`, counting the moving regions as dynamic); the reference's trust
    raises them to at least +2 (:func:`flagged`) while it is the reference. evidence: ``L``
    with the moving regions at least ``params.motion_vote``, what is carried to later
    references (:func:`propagate`) and updated by each estimate.

    Why the coherent regions are not written into the evidence: coherence is a spatial
    smoothing of the evidence, not an observation, and a region decision covers all of a
    region, also the static pixels of a region that holds part of a person. Carried at +2
    they counted towards the next reference's regions, whose boundaries differ, so each
    reference could flag more of the static scene around a person, and static votes undo +2
    only slowly (8 views; behind a person few views see it; docs/decisions/segmentation.md).
    """
    valid = depth > 0
    moved = moved & valid
    flags = moved | coherent_flags(jnp.where(moved, jnp.maximum(L, 2.0), L), depth, None, params, labels=labels)
    return jnp.where(moved, jnp.maximum(L, params.motion_vote), L), flags


def flagged(L, flags):
    """The log-odds the trust is computed from: ``L`` raised to at least +2 where ``flags``."""
    return jnp.where(flags, jnp.maximum(L, 2.0), L)


def static_weight(L, gain=1.0, share=None):
    """Trust in each pixel of the map L (h, w) as static scene: sigmoid(-g * L), in (0, 1). g = 1
    gives the map's probability that the pixel is static; every g > 0 trusts the same pixels
    (weight >= 0.5 where L <= 0) and a larger one sharpens the weights towards 0 and 1.

    g is ``gain`` (``TrackConfig.trust_gain``) where the map trusts under ``share`` of its pixels
    (the fraction with L <= 0; ``TrackConfig.trust_share``), else 1; ``share`` None: ``gain``
    everywhere. Where the static scene is the minority, the pixels the map is unsure of (people
    it has half seen move) would outweigh it at their probability; where it is the majority, the
    probability is the better weight, and a sequence that starts with people in view, before the
    map has evidence, is not led onto them (docs/decisions/trust-gain.md)."""
    if share is not None:
        trusted = jnp.mean((L <= 0).astype(jnp.float32))
        gain = jnp.where(trusted < share, gain, 1.0)
    return jax.nn.sigmoid(-gain * L)


def upsample(x, shape, factor: int = 1 << MAP_LEVEL):
    """(h, w) -> (H, W) by pixel repetition, ``factor`` times in each direction (default: a
    map-level array to full resolution), the last row and column repeated to fill ``shape``."""
    H, W = shape
    y = jnp.repeat(jnp.repeat(x, factor, axis=0), factor, axis=1)[:H, :W]
    return jnp.pad(y, ((0, H - y.shape[0]), (0, W - y.shape[1])), mode="edge")
