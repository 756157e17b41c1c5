"""Camera and person trajectories for the paper's Table II sequences, and :func:`make_sequence`.

All poses are (4, 4) float64 in the synthetic world frame of
:mod:`jaxvo.synthetic.scene` (x right, y down, z forward, metres). Camera
trajectories give ``T_world_cam`` (camera-to-world); person trajectories give
``T_world_obj`` of the body centre. Every trajectory is an object with a
``pose(t) -> (4, 4)`` method, ``t`` in seconds, smooth in ``t`` and
deterministic (random ones are fixed by a seed at construction).

Sequences (:data:`SEQUENCES`):

* ``seq0``: hand-held camera (smooth random walk, ~1 cm and ~1 deg per frame
  at 30 Hz) in the static room;
* ``seq1``: fixed camera, one person walking across the view at ~2 m;
* ``seq2``: camera on a pan-tilt head panning about the vertical (world y)
  axis at 2 deg/s, one person walking;
* ``seq3``: as seq2 with two persons;
* ``handheld-fast``: hand-held camera (faster) with a person moving fast and
  close (0.8-1.4 m), covering most of the image at times.
* ``crowd``: for long runs (drift over hundreds of frames): hand-held camera panning slowly
  back and forth (+-20 deg over 24 s) and three persons walking on their own paths at 1.2-3.0 m,
  each 0.5-0.6 m wide, so that at times they cover half the image.
* ``crowd-close``: as ``crowd``, but two of the three persons come close (0.9-1.8 m) and each
  walks into the view, stands there for seconds, walks out and waits out of view: people who
  stand still long enough to look static, then move, over up to half the image or more.

The ground-truth relative motion of a pair (ref, cur) = frames (k, k+1) is
``T_cur_ref = inv(T_world_cur) @ T_world_ref`` (:meth:`SyntheticSequence.relative_pose`).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Optional

import numpy as np

from jaxvo import geometry
from jaxvo.camera import DEFAULT, Camera
from jaxvo.synthetic.render import RenderResult, SensorModel, render
from jaxvo.synthetic.scene import FLOOR_Y, Scene, make_person, make_room

__all__ = [
    "FixedPose", "PanTilt", "Handheld", "Sweep", "Walk", "SyntheticSequence", "make_sequence", "SEQUENCES", "FPS",
    "rot_x", "rot_y",
]

FPS = 30.0
SEQUENCES = ("seq0", "seq1", "seq2", "seq3", "handheld-fast", "crowd", "crowd-close")


def rot_x(a: float) -> np.ndarray:
    """(3, 3) rotation by ``a`` radians about x (positive ``a`` tilts a y-down camera's view up)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    """(3, 3) rotation by ``a`` radians about y (the vertical axis of the y-down world)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _T(R, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


@dataclasses.dataclass(frozen=True)
class FixedPose:
    """A constant pose: ``pose(t) = T`` ((4, 4))."""
    T: np.ndarray

    def pose(self, t: float) -> np.ndarray:
        return np.array(self.T, float)


@dataclasses.dataclass(frozen=True)
class PanTilt:
    """Camera on a pan-tilt head at ``position``: pans about world y at ``rate`` rad/s, fixed ``tilt`` (rad).

    ``T_world_cam(t) = [rot_y(pan0 + rate * t) @ rot_x(tilt), position]``; the
    optical centre is on the pan axis (pure rotation).
    """
    rate: float = math.radians(2.0)
    tilt: float = math.radians(-8.0)
    pan0: float = 0.0
    position: tuple = (0.0, 0.0, 0.0)

    def pose(self, t: float) -> np.ndarray:
        return _T(rot_y(self.pan0 + self.rate * t) @ rot_x(self.tilt), self.position)


@dataclasses.dataclass(frozen=True)
class Handheld:
    """Smooth random hand-held motion around a base pose, deterministic from ``seed``.

    Each of the 6 DoF is a sum of 3 sinusoids (frequencies 0.15-0.8 Hz, random
    phases). ``trans_amp`` (m) and ``rot_amp`` (rad) are per-component
    amplitudes, scaled by ``speed``; with the defaults the camera moves about
    1 cm and 1 deg per frame at 30 Hz. ``T_world_cam(t) = base @ [exp_so3(w(t)), v(t)]``.
    """
    seed: int = 0
    trans_amp: float = 0.1
    rot_amp: float = math.radians(4.0)
    speed: float = 1.0
    base: tuple = ((1.0, 0.0, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 1.0, 0.0), (0.0, 0.0, 0.0, 1.0))

    def _params(self):
        rng = np.random.default_rng(np.random.SeedSequence([int(self.seed), 0x4A78]))
        freq = rng.uniform(0.15, 0.8, (6, 3)) * self.speed
        phase = rng.uniform(0, 2 * np.pi, (6, 3))
        amp = rng.uniform(0.5, 1.0, (6, 3))
        amp[:3] *= self.rot_amp
        amp[3:] *= self.trans_amp
        return freq, phase, amp

    def pose(self, t: float) -> np.ndarray:
        freq, phase, amp = self._params()
        x = (amp * (np.sin(2 * np.pi * freq * t + phase) - np.sin(phase))).sum(1)   # 0 at t = 0
        T = _T(geometry.exp_so3(x[:3]), x[3:])
        return np.asarray(self.base, float) @ T


@dataclasses.dataclass(frozen=True)
class Sweep:
    """A hand-held camera (:class:`Handheld`) on a slow pan about the vertical (world y) axis:
    ``T_world_cam(t) = rot_y(amplitude sin(2 pi t / period)) @ handheld(t)`` (radians, seconds)."""
    handheld: Handheld
    amplitude: float = math.radians(20.0)
    period: float = 24.0

    def pose(self, t: float) -> np.ndarray:
        return _T(rot_y(self.amplitude * math.sin(2 * np.pi * t / self.period)), (0.0, 0.0, 0.0)) \
            @ self.handheld.pose(t)


@dataclasses.dataclass(frozen=True)
class Walk:
    """A person walking back and forth between world points ``a`` and ``b`` ((3,) metres, body centre).

    Position ``a + s(t) (b - a)`` with ``s = (1 - cos(2 pi t / period + phase)) / 2``
    (smooth turns at the ends); the body turns to face the walking direction
    plus ``yaw`` (rad) and sways by ``sway`` rad. Peak speed ``pi |b - a| / period``.
    ``dwell`` in [0, 0.5): the fraction of each period spent standing at each end (the cycle from
    ``phase``: standing at ``a``, walking to ``b``, standing there, walking back); each walk is the
    half-cosine from rest to rest, so the peak speed becomes ``pi |b - a| / ((1 - 2 dwell) period)``.
    """
    a: tuple
    b: tuple
    period: float = 6.0
    phase: float = 0.0
    yaw: float = 0.0
    sway: float = math.radians(8.0)
    dwell: float = 0.0

    def __post_init__(self):
        # each walk needs part of the half period: 0.5 would leave none (and divide by zero)
        if not 0.0 <= self.dwell < 0.5:
            raise ValueError(f"Walk.dwell must be in [0, 0.5), got {self.dwell}")

    def _progress(self, t: float) -> float:
        """s(t) in [0, 1]: how far along a -> b the body centre is at time t (seconds)."""
        w = 2 * np.pi / self.period
        if self.dwell == 0.0:
            return 0.5 * (1 - math.cos(w * t + self.phase))
        u = ((w * t + self.phase) / (2 * np.pi)) % 1.0      # where in the cycle, [0, 1)
        d, half = self.dwell, 0.5
        if u < d:                                            # standing at a
            return 0.0
        if u < half:                                         # walking a -> b
            return 0.5 * (1 - math.cos(np.pi * (u - d) / (half - d)))
        if u < half + d:                                     # standing at b
            return 1.0
        return 0.5 * (1 + math.cos(np.pi * (u - half - d) / (half - d)))   # walking b -> a

    def pose(self, t: float) -> np.ndarray:
        a, b = np.asarray(self.a, float), np.asarray(self.b, float)
        w = 2 * np.pi / self.period
        s = self._progress(t)
        p = a + s * (b - a)
        heading = math.atan2(b[0] - a[0], b[2] - a[2])
        ang = heading + self.yaw + self.sway * math.sin(2 * w * t + self.phase)
        return _T(rot_y(ang), p)


@dataclasses.dataclass(eq=False)
class SyntheticSequence:
    """A synthetic RGB-D sequence with exact ground truth.

    name: sequence name. scene: the :class:`Scene` (moving persons included).
    camera: intrinsics and size. timestamps: (N,) float64 seconds (frame k at
    ``k / fps``), also the render time. poses: (N, 4, 4) float64 ``T_world_cam``.
    camera_motion: the camera trajectory object. persons: the persons'
    trajectory objects (``pose(t) -> T_world_obj``), in scene order.
    """
    name: str
    scene: Scene
    camera: Camera
    timestamps: np.ndarray
    poses: np.ndarray
    camera_motion: object
    persons: list
    seed: int = 0

    def __len__(self) -> int:
        return len(self.timestamps)

    def render(self, k: int, *, sensor: Optional[SensorModel] = None, rng=None, supersample: int = 1) -> RenderResult:
        """Render frame ``k`` (pose ``poses[k]`` at time ``timestamps[k]``)."""
        return render(self.scene, self.camera, self.poses[k], float(self.timestamps[k]),
                      sensor=sensor, rng=rng, supersample=supersample)

    def relative_pose(self, k: int, j: Optional[int] = None) -> np.ndarray:
        """Ground-truth ``T_cur_ref`` (4, 4) for ref = frame ``k``, cur = frame ``j`` (default ``k + 1``)."""
        j = k + 1 if j is None else j
        return geometry.inverse(self.poses[j]) @ self.poses[k]


def make_sequence(name: str, frames: int = 300, seed: int = 0, *, camera: Camera = DEFAULT,
                  fps: float = FPS) -> SyntheticSequence:
    """Build one of :data:`SEQUENCES` with ``frames`` frames at ``fps`` Hz, deterministic from ``seed``.

    The room comes from ``make_room(seed)``; camera shake, person textures
    and person paths are drawn from generators derived from ``seed``.
    """
    if name not in SEQUENCES:
        raise ValueError(f"unknown synthetic sequence {name!r}; choose one of {', '.join(SEQUENCES)}")
    frames = int(frames)
    if frames < 1:
        raise ValueError(f"frames must be >= 1, got {frames}")
    scene = make_room(seed)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5E9, SEQUENCES.index(name)]))
    ts = np.arange(frames, dtype=np.float64) / fps
    duration = max(ts[-1], 1.0)
    tilt = math.radians(-8.0)
    base = _T(rot_x(tilt), (0.0, 0.0, 0.0))
    persons = []
    ph = rng.uniform(0, 2 * np.pi)

    def add_person(motion, kind, width=0.5, height=1.7, depth=0.3):
        scene.add(make_person(rng, motion, kind=kind, width=width, height=height, depth=depth,
                              name=f"person{len(persons)}"))
        persons.append(motion)

    yc = FLOOR_Y - 0.85   # body centre of a 1.7 m person standing on the floor
    if name == "seq0":
        cam = Handheld(seed=seed, base=tuple(map(tuple, base)))
    elif name == "seq1":
        cam = FixedPose(base)
        add_person(Walk((-1.1, yc, 2.0 + rng.uniform(-0.2, 0.2)), (1.1, yc, 1.8 + rng.uniform(-0.2, 0.2)),
                        period=rng.uniform(5.0, 7.0), phase=ph), "cylinder")
    elif name in ("seq2", "seq3"):
        rate = math.radians(2.0)
        pan0 = -0.5 * rate * duration          # centre the pan on the +z direction
        cam = PanTilt(rate=rate, tilt=tilt, pan0=pan0)
        add_person(Walk((-1.1, yc, 2.0 + rng.uniform(-0.2, 0.2)), (1.1, yc, 1.7 + rng.uniform(-0.2, 0.2)),
                        period=rng.uniform(5.0, 7.0), phase=ph), "cylinder")
        if name == "seq3":
            add_person(Walk((1.3, yc + 0.05, 2.5), (-1.2, yc + 0.05, 2.7), period=rng.uniform(6.0, 8.0),
                            phase=ph + np.pi * 0.7, yaw=np.pi / 2), "box", width=0.55, height=1.8, depth=0.3)
    elif name == "crowd":
        cam = Sweep(Handheld(seed=seed, base=tuple(map(tuple, base))))
        for n in range(3):
            # each crosses the view on its own path (not following the camera), near ones first
            z0, z1 = rng.uniform(1.2, 2.0) + 0.5 * n, rng.uniform(1.2, 2.0) + 0.5 * n
            side = 1.0 if n % 2 == 0 else -1.0
            add_person(Walk((-1.6 * side, yc, z0), (1.6 * side, yc, z1), period=rng.uniform(6.0, 10.0),
                            phase=rng.uniform(0, 2 * np.pi)),
                       "cylinder" if n % 2 == 0 else "box", width=rng.uniform(0.5, 0.6), depth=0.3)
    elif name == "crowd-close":
        cam = Sweep(Handheld(seed=seed, base=tuple(map(tuple, base))))
        for n in range(3):
            # each walks in from outside the view to a spot in it, stands there for seconds and
            # walks out again (on its own path, not following the camera); the first two close
            z0, z1 = rng.uniform(0.9, 1.3) + 0.5 * n, rng.uniform(0.9, 1.3) + 0.5 * n
            side = 1.0 if n % 2 == 0 else -1.0
            add_person(Walk((-1.8 * side, yc, z0), (rng.uniform(-0.3, 0.3), yc, z1), period=rng.uniform(8.0, 14.0),
                            phase=rng.uniform(0, 2 * np.pi), dwell=rng.uniform(0.15, 0.3)),
                       "cylinder" if n % 2 == 0 else "box", width=rng.uniform(0.5, 0.6), depth=0.3)
    else:  # handheld-fast
        cam = Handheld(seed=seed, speed=1.6, base=tuple(map(tuple, base)))
        add_person(Walk((-1.0, yc, 1.4), (0.7, yc, 0.8), period=rng.uniform(2.2, 2.8), phase=ph, yaw=np.pi / 2),
                   "box", width=0.7, height=1.7, depth=0.35)
    poses = np.stack([cam.pose(float(t)) for t in ts])
    return SyntheticSequence(name, scene, camera, ts, poses, cam, persons, int(seed))
