"""Synthetic indoor scenes: textured primitives, procedural textures, the default room.

World frame of the synthetic scenes: x right, **y down** (gravity is +y), z
forward, metres. A camera with ``T_world_cam = I`` therefore looks
horizontally along +z with its image upright. The default room
(:func:`make_room`) spans x in [-2.6, 2.6], y in [-1.5, 1.3] (the floor is the
plane y = 1.3, i.e. the camera at the origin is 1.3 m above the floor) and
z in [-1.6, 3.2]; the furniture leaves a clear region of about 0.7 m around
the origin for the camera.

Every object has a shape (:class:`Box`, :class:`Cylinder` or :class:`Rect`),
defined in its own local frame, a pose ``T_world_obj`` ((4, 4) float64,
maps local points into the world) and optionally a ``motion``: any object
with a ``pose(t) -> (4, 4)`` method giving ``T_world_obj`` at time ``t``
(seconds). Objects with a motion are "moving" (persons); they carry their
textures with them.

Textures are defined in each face's own 2-D surface coordinates (metres), so
a surface point has the same colour from every view (Lambertian albedo, no
view-dependent shading). They are precomputed procedural images (multi-octave
value noise, soft-edged blobs, anti-aliased shapes, stripes) sampled with
bilinear filtering at the exact ray hit; the finest content has a wavelength
of a few centimetres (band-limited by a final blur) so the rendered image is
smooth at the pixel scale of a 640x480 Kinect-like camera at 0.5-4 m.
"""
from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, Optional

import cv2
import numpy as np

__all__ = [
    "Texture", "Box", "Cylinder", "Rect", "SceneObject", "Scene",
    "make_texture", "make_object", "make_person", "make_room", "ROOM_BOUNDS", "FLOOR_Y", "TEXEL",
]

TEXEL = 0.005          # metres per texel of the procedural textures
FLOOR_Y = 1.3          # the floor plane of the default room (world y, y down)
ROOM_BOUNDS = np.array([[-2.6, 2.6], [-1.5, FLOOR_Y], [-1.6, 3.2]])  # (3, 2) min/max per world axis


# --------------------------------------------------------------------------- textures

@dataclasses.dataclass(frozen=True, eq=False)
class Texture:
    """An albedo image over a face's 2-D surface coordinates.

    ``image``: (rows, cols, 3) float32 RGB on 0-255; texel ``(i, j)`` (row,
    col) has its centre at surface coordinates ``s = (j + 0.5) * texel``,
    ``t = (i + 0.5) * texel`` (metres). Outside the image the border is
    repeated.
    """
    image: np.ndarray
    texel: float = TEXEL

    def __post_init__(self):
        img = np.asarray(self.image, np.float32)
        object.__setattr__(self, "image", img)
        # channel-planar copy for fast 1-D gathers
        object.__setattr__(self, "_planar", np.ascontiguousarray(img.transpose(2, 0, 1)).reshape(3, -1))

    def sample(self, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Bilinear lookup at surface coordinates ``s, t`` ((M,) metres) -> (M, 3) float32 RGB."""
        h, w = self.image.shape[:2]
        inv = np.float32(1.0 / self.texel)
        x = np.clip(s.astype(np.float32) * inv - np.float32(0.5), 0, np.float32(w - 1.001))
        y = np.clip(t.astype(np.float32) * inv - np.float32(0.5), 0, np.float32(h - 1.001))
        x0 = x.astype(np.int32)
        y0 = y.astype(np.int32)
        ax = x - x0
        ay = y - y0
        i00 = y0 * w + x0
        i01 = i00 + 1
        i10 = i00 + w
        i11 = i10 + 1
        out = np.empty((s.shape[0], 3), np.float32)
        for c in range(3):
            p = self._planar[c]
            c00 = p.take(i00)
            c01 = p.take(i01)
            top = c00 + ax * (c01 - c00)
            c10 = p.take(i10)
            bot = c10 + ax * (p.take(i11) - c10)
            out[:, c] = top + ay * (bot - top)
        return out


def _noise(rng: np.random.Generator, h: int, w: int, cell: float) -> np.ndarray:
    """(h, w) float32 smooth value noise in ~[0, 1], lattice spacing ``cell`` texels (bicubic)."""
    gh = int(math.ceil(h / cell)) + 3
    gw = int(math.ceil(w / cell)) + 3
    g = rng.random((gh, gw), dtype=np.float32)
    up = cv2.resize(g, (int(round(gw * cell)), int(round(gh * cell))), interpolation=cv2.INTER_CUBIC)
    o = int(cell)
    return np.clip(up[o:o + h, o:o + w], -0.2, 1.2)


def _random_colour(rng: np.random.Generator, lo: float = 20, hi: float = 235) -> np.ndarray:
    return rng.uniform(lo, hi, 3).astype(np.float32)


def make_texture(rng: np.random.Generator, width_m: float, height_m: float, *,
                 texel: float = TEXEL, style: str = "rich", blur: float = 1.5) -> Texture:
    """A rich, non-repeating procedural texture covering ``width_m x height_m`` metres.

    Layers (all random from ``rng``): a multi-octave value-noise luminance
    mapped between two colours (wavelengths ~0.8 m down to ~4 cm), two layers
    of soft-edged colour blobs (~0.5 m and ~0.15 m), anti-aliased discs,
    rectangles and polygons of 2-25 cm, and (style "rich") stripes of 3-10 cm
    period in patches. A final Gaussian blur of ``blur`` texels band-limits
    the result. ``style="person"`` uses bolder, clothing-like patterns.
    """
    w = max(4, int(math.ceil(width_m / texel)) + 2)
    h = max(4, int(math.ceil(height_m / texel)) + 2)
    c_per_m = 1.0 / texel
    # multi-octave luminance
    lum = np.zeros((h, w), np.float32)
    total = 0.0
    for wl, amp in ((0.8, 1.0), (0.3, 0.9), (0.11, 0.8), (0.04, 0.6)):
        lum += np.float32(amp) * _noise(rng, h, w, wl * c_per_m)
        total += amp
    lum /= np.float32(total)
    lum = np.clip((lum - 0.5) * 2.2 + 0.5, 0, 1)
    c0, c1 = _random_colour(rng, 10, 120), _random_colour(rng, 130, 250)
    img = c0 + lum[..., None] * (c1 - c0)
    # soft-edged blobs (sharp but band-limited edges)
    for wl, k in ((0.5, 14.0), (0.15, 10.0)):
        n = _noise(rng, h, w, wl * c_per_m)
        thr = rng.uniform(0.55, 0.7)
        a = 1.0 / (1.0 + np.exp(np.clip(-(n - thr) * k * wl * c_per_m / 10.0, -60, 60)))
        col = _random_colour(rng)
        img += a[..., None] * (col - img)
    # stripes in patches
    if style in ("rich", "person"):
        period = rng.uniform(0.03, 0.1) * c_per_m
        ang = rng.uniform(0, np.pi)
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        ph = (np.cos(ang) * xx + np.sin(ang) * yy) * np.float32(2 * np.pi / period)
        stripes = np.tanh(3.0 * np.sin(ph)) * 0.5 + 0.5
        patch = _noise(rng, h, w, 0.6 * c_per_m)
        m = np.clip((patch - (0.55 if style == "rich" else 0.35)) * 8.0, 0, 1) * stripes
        col = _random_colour(rng)
        img += m[..., None].astype(np.float32) * (col - img)
    # anti-aliased shapes
    canvas = np.clip(img, 0, 255).astype(np.uint8)
    area = width_m * height_m
    n_shapes = int(min(400, max(3, area * (25 if style == "rich" else 12))))
    for _ in range(n_shapes):
        size = math.exp(rng.uniform(math.log(0.02), math.log(0.25))) * c_per_m
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        col = tuple(int(c) for c in rng.integers(0, 256, 3))
        kind = rng.integers(0, 3)
        shift = 4
        sc = 1 << shift
        if kind == 0:
            cv2.circle(canvas, (int(cx * sc), int(cy * sc)), int(size * sc / 2), col, -1, cv2.LINE_AA, shift)
        else:
            nv = 4 if kind == 1 else int(rng.integers(3, 7))
            a0 = rng.uniform(0, 2 * np.pi)
            angs = a0 + np.sort(rng.uniform(0, 2 * np.pi, nv)) if kind == 2 else a0 + np.arange(4) * np.pi / 2
            rad = size / 2 * (rng.uniform(0.5, 1.0, nv) if kind == 2 else np.ones(nv))
            pts = np.stack([cx + rad * np.cos(angs), cy + rad * np.sin(angs)], -1)
            cv2.fillPoly(canvas, [np.round(pts * sc).astype(np.int32)], col, cv2.LINE_AA, shift)
    img = canvas.astype(np.float32)
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur, borderType=cv2.BORDER_REFLECT)
    return Texture(np.ascontiguousarray(img, dtype=np.float32), texel)


# --------------------------------------------------------------------------- shapes

@dataclasses.dataclass(frozen=True)
class Box:
    """Box centred on its local origin with half-extents ``half`` (3,) metres along local x, y, z.

    ``inside=True`` makes it an enclosure seen from within (the room): rays
    from inside hit its far side. Faces, in texture order: ``2*axis + (0 for
    the -side, 1 for the +side)``; face ``axis`` uses surface coordinates
    ``(p_i + half_i, p_j + half_j)`` with ``(i, j)`` the two other axes in
    increasing order.
    """
    half: tuple
    inside: bool = False

    n_faces = 6

    def face_sizes(self):
        h = self.half
        out = []
        for k in range(3):
            i, j = [a for a in range(3) if a != k]
            out += [(2 * h[i], 2 * h[j])] * 2
        return out

    def corners(self) -> np.ndarray:
        h = np.asarray(self.half, float)
        s = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
        return s * h


@dataclasses.dataclass(frozen=True)
class Cylinder:
    """Cylinder with its axis along local y, radius ``radius``, from ``y0`` to ``y1`` (metres, y0 < y1).

    Faces: 0 = side (surface coordinates ``(radius * (atan2(z, x) + pi), y - y0)``),
    1 = cap at y0, 2 = cap at y1 (coordinates ``(x + radius, z + radius)``).
    """
    radius: float
    y0: float
    y1: float

    n_faces = 3

    def face_sizes(self):
        r = self.radius
        return [(2 * np.pi * r, self.y1 - self.y0), (2 * r, 2 * r), (2 * r, 2 * r)]

    def corners(self) -> np.ndarray:
        r = self.radius
        return np.array([[x, y, z] for x in (-r, r) for y in (self.y0, self.y1) for z in (-r, r)], float)


@dataclasses.dataclass(frozen=True)
class Rect:
    """Two-sided rectangle in the local plane z = 0, |x| <= hx, |y| <= hy (metres).

    One face, surface coordinates ``(x + hx, y + hy)``.
    """
    hx: float
    hy: float

    n_faces = 1

    def face_sizes(self):
        return [(2 * self.hx, 2 * self.hy)]

    def corners(self) -> np.ndarray:
        return np.array([[x, y, 0.0] for x in (-self.hx, self.hx) for y in (-self.hy, self.hy)], float)


@dataclasses.dataclass(eq=False)
class SceneObject:
    """A textured shape with a pose.

    ``pose``: (4, 4) float64 ``T_world_obj`` for a static object. ``motion``:
    optional object with ``pose(t) -> (4, 4) T_world_obj`` (t in seconds);
    when given the object is moving and ``pose`` is ignored. ``textures``:
    one :class:`Texture` per face of ``shape``.
    """
    shape: Any
    textures: tuple
    pose: np.ndarray = dataclasses.field(default_factory=lambda: np.eye(4))
    motion: Optional[Any] = None
    name: str = ""

    @property
    def moving(self) -> bool:
        return self.motion is not None

    def pose_at(self, t: float) -> np.ndarray:
        """``T_world_obj`` (4, 4) float64 at time ``t`` (seconds)."""
        if self.motion is None:
            return np.asarray(self.pose, float)
        return np.asarray(self.motion.pose(float(t)), float)


@dataclasses.dataclass(eq=False)
class Scene:
    """A list of :class:`SceneObject`; ``object_id`` in renders indexes ``objects`` (-1 = nothing hit)."""
    objects: list
    seed: Optional[int] = None

    @property
    def moving_ids(self) -> list:
        return [i for i, o in enumerate(self.objects) if o.moving]

    def add(self, obj: SceneObject) -> int:
        """Append ``obj``; returns its object id."""
        self.objects.append(obj)
        return len(self.objects) - 1

    def copy(self) -> "Scene":
        return Scene(list(self.objects), self.seed)


def _pose(R=None, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    T[:3, 3] = t
    return T


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def make_object(rng: np.random.Generator, shape, pose=None, motion=None, name: str = "",
                style: str = "rich") -> SceneObject:
    """A :class:`SceneObject` with fresh procedural textures (one per face) drawn from ``rng``."""
    tex = tuple(make_texture(rng, w, h, style=style) for (w, h) in shape.face_sizes())
    return SceneObject(shape, tex, np.eye(4) if pose is None else np.asarray(pose, float), motion, name)


def make_person(rng: np.random.Generator, motion, kind: str = "cylinder", height: float = 1.7,
                width: float = 0.5, depth: float = 0.3, name: str = "person") -> SceneObject:
    """A person-like moving occluder, its local origin at the body centre (local y down).

    ``kind="cylinder"``: radius ``width/2``, height ``height``; ``kind="box"``:
    ``width x height x depth`` metres. ``motion.pose(t)`` gives ``T_world_obj``
    of the body centre (for a person standing on the default floor the
    centre is at world ``y = FLOOR_Y - height/2``).
    """
    if kind == "cylinder":
        shape = Cylinder(width / 2, -height / 2, height / 2)
    elif kind == "box":
        shape = Box((width / 2, height / 2, depth / 2))
    else:
        raise ValueError(f"person kind must be 'cylinder' or 'box', got {kind!r}")
    return make_object(rng, shape, motion=motion, name=name, style="person")


def make_room(seed: int = 0, *, furniture: int = 8) -> Scene:
    """The default textured room (deterministic from ``seed``), static objects only.

    A 5.2 x 2.8 x 4.8 m enclosure (:data:`ROOM_BOUNDS`, world y down, floor at
    y = 1.3) with a table, boxes, cabinets, shelves and a couple of
    cylinders (about ``furniture`` pieces), each with its own texture, placed
    randomly but clear of a ~0.7 m region around the origin where the camera
    lives. From the origin looking along +z the far wall is 3.2 m away, so
    typical depths are 1-4 m. Add persons with :meth:`Scene.add`.

    Returns a fresh :class:`Scene` (a new object list, so ``add`` is safe); the static objects and
    their textures are cached and shared between rooms of the same seed (treat them as read-only).
    """
    return Scene(list(_make_room_objects(int(seed), int(furniture))), seed)


@functools.lru_cache(maxsize=2)
def _make_room_objects(seed: int = 0, furniture: int = 8) -> tuple:
    """Cached static objects of :func:`make_room` (a tuple)."""
    rng = np.random.default_rng(seed)
    b = ROOM_BOUNDS
    centre = b.mean(1)
    half = tuple((b[:, 1] - b[:, 0]) / 2)
    objs = [make_object(rng, Box(half, inside=True), _pose(t=centre), name="room")]
    fy = FLOOR_Y

    def box_on_floor(x, z, sx, sy, sz, yaw, name, y_bottom=fy):
        return make_object(rng, Box((sx / 2, sy / 2, sz / 2)),
                           _pose(_rot_y(yaw), (x, y_bottom - sy / 2, z)), name=name)

    # a table in front of the camera (top + one block as legs) and objects on it
    tx, tz = rng.uniform(-0.4, 0.4), rng.uniform(1.5, 2.0)
    tyaw = rng.uniform(-0.3, 0.3)
    objs.append(box_on_floor(tx, tz, 1.6, 0.05, 0.8, tyaw, "table_top", y_bottom=fy - 0.7))
    objs.append(box_on_floor(tx, tz, 1.2, 0.7, 0.5, tyaw, "table_base"))
    for k in range(3):
        sx, sy, sz = rng.uniform(0.12, 0.4), rng.uniform(0.1, 0.45), rng.uniform(0.12, 0.35)
        ox = tx + rng.uniform(-0.6, 0.6)
        oz = tz + rng.uniform(-0.2, 0.2)
        objs.append(box_on_floor(ox, oz, sx, sy, sz, rng.uniform(-0.8, 0.8), f"item{k}", y_bottom=fy - 0.75))
    # furniture along the walls
    zones = [("far", (-2.0, 2.0), (2.6, 2.9)), ("left", (-2.3, -2.0), (-0.8, 2.6)),
             ("right", (2.0, 2.3), (-0.8, 2.6)), ("back", (-2.0, 2.0), (-1.3, -1.1))]
    for k in range(max(0, furniture - 4)):
        name, xr, zr = zones[k % len(zones)]
        x, z = rng.uniform(*xr), rng.uniform(*zr)
        sx, sy, sz = rng.uniform(0.4, 1.1), rng.uniform(0.5, 2.0), rng.uniform(0.3, 0.5)
        yaw = (np.pi / 2 if name in ("left", "right") else 0.0) + rng.uniform(-0.25, 0.25)
        objs.append(box_on_floor(x, z, sx, sy, sz, yaw, f"cabinet_{name}{k}"))
    for k in range(2):
        side = -1 if k == 0 else 1
        x, z = side * rng.uniform(1.1, 1.7), rng.uniform(1.8, 2.6)
        r, hgt = rng.uniform(0.1, 0.25), rng.uniform(0.5, 2.8)
        y1 = fy
        y0 = max(b[1, 0], fy - hgt)
        objs.append(make_object(rng, Cylinder(r, y0, y1), _pose(t=(x, 0.0, z)), name=f"column{k}"))
    # a poster on the far wall (coplanar-ish edges, a few mm in front)
    objs.append(make_object(rng, Rect(rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.5)),
                            _pose(t=(rng.uniform(-1.0, 1.0), rng.uniform(-0.9, -0.3), b[2, 1] - 0.01)),
                            name="poster"))
    return tuple(objs)
