"""PLY point clouds: write a binary little-endian PLY, read binary or ASCII PLY vertices.

Points are (N, 3) metres in whatever frame the caller uses (jaxvo's maps: the world frame of the
trajectory, T_world_cam); colours (N, 3) uint8 RGB. The files open in Open3D
(``o3d.io.read_point_cloud``), MeshLab and CloudCompare.
"""
from __future__ import annotations

from pathlib import Path
from typing import Dict, Optional, Tuple

import numpy as np

__all__ = ["write_ply", "read_ply", "read_ply_vertices"]

_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def write_ply(path, points, colors=None, moving=None) -> Path:
    """Write a binary little-endian PLY point cloud: float x, y, z, (if given) uchar red, green,
    blue and (if given) uchar moving (1 = a point on something that moves, 0 = static).

    points: (N, 3) float metres. colors: (N, 3) uint8 RGB (floats in [0, 1] are scaled by 255).
    moving: (N,) bool. Opens in Open3D (``o3d.io.read_point_cloud``), MeshLab and CloudCompare
    (which shows ``moving`` as a scalar field). Returns the Path.
    """
    path = Path(path)
    P = np.asarray(points, np.float32).reshape(-1, 3)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    C = None
    if colors is not None:
        C = np.asarray(colors)
        if C.shape != P.shape:
            raise ValueError(f"colors must be (N, 3) like points {P.shape}, got {C.shape}")
        if np.issubdtype(C.dtype, np.floating):
            C = np.clip(np.round(C * 255.0), 0, 255)
        C = C.astype(np.uint8)
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    if moving is not None:
        moving = np.asarray(moving, bool).reshape(-1)
        if moving.shape != (len(P),):
            raise ValueError(f"moving must be (N,) like points {P.shape}, got {moving.shape}")
        fields += [("moving", "u1")]
    rec = np.empty(len(P), dtype=fields)
    rec["x"], rec["y"], rec["z"] = P[:, 0], P[:, 1], P[:, 2]
    if C is not None:
        rec["red"], rec["green"], rec["blue"] = C[:, 0], C[:, 1], C[:, 2]
    if moving is not None:
        rec["moving"] = moving
    header = ["ply", "format binary_little_endian 1.0", "comment written by jaxvo",
              f"element vertex {len(P)}", "property float x", "property float y", "property float z"]
    if C is not None:
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    if moving is not None:
        header += ["property uchar moving"]
    header += ["end_header"]
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(rec.tobytes())
    return path


def read_ply(path) -> Tuple[np.ndarray, Optional[np.ndarray]]:
    """Read the vertices of a PLY file (binary little/big endian or ASCII; scalar vertex properties).

    Returns ``(points (N, 3) float64, colors (N, 3) uint8 or None)``. Other elements after the
    vertices (faces) are ignored. Raises ValueError naming the file for malformed input.
    """
    rec = read_ply_vertices(path)
    P = np.stack([np.asarray(rec[c], np.float64) for c in "xyz"], 1)
    C = None
    if all(c in rec for c in ("red", "green", "blue")):
        C = np.stack([np.asarray(rec[c]) for c in ("red", "green", "blue")], 1)
        if np.issubdtype(C.dtype, np.floating) and C.max(initial=0) <= 1.0:
            C = C * 255.0
        C = np.clip(np.round(C), 0, 255).astype(np.uint8)
    return P, C


def read_ply_vertices(path) -> Dict[str, np.ndarray]:
    """Every scalar vertex property of a PLY file by name, (N,) each (e.g. x, y, z, red, green,
    blue and jaxvo's ``moving``). Raises ValueError naming the file for malformed input."""
    path = Path(path)
    with open(path, "rb") as f:
        data = f.read()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError(f"{path}: not a PLY file")
    nl = data.find(b"\n", end)
    header = data[:end].decode("ascii", "replace").splitlines()
    body = data[nl + 1:]
    fmt, elements, cur = None, [], None
    for ln in header:
        t = ln.split()
        if not t:
            continue
        if t[0] == "format":
            fmt = t[1]
        elif t[0] == "element":
            cur = [t[1], int(t[2]), []]
            elements.append(cur)
        elif t[0] == "property" and cur is not None:
            if t[1] == "list":
                cur[2].append((t[-1], None))
            else:
                if t[1] not in _PLY_TYPES:
                    raise ValueError(f"{path}: unknown PLY property type {t[1]!r}")
                cur[2].append((t[2], _PLY_TYPES[t[1]]))
    if fmt not in ("binary_little_endian", "binary_big_endian", "ascii"):
        raise ValueError(f"{path}: unsupported PLY format {fmt!r}")
    if not elements or elements[0][0] != "vertex":
        raise ValueError(f"{path}: the first PLY element is not 'vertex'")
    _, n, props = elements[0]
    if any(t is None for _, t in props):
        raise ValueError(f"{path}: list properties on vertices are not supported")
    if fmt == "ascii":
        rows = body.decode("ascii").split("\n")[:n]
        arr = np.loadtxt(rows, ndmin=2) if n else np.zeros((0, len(props)))
        rec = {name: arr[:, k] for k, (name, _) in enumerate(props)}
    else:
        e = "<" if fmt == "binary_little_endian" else ">"
        dt = np.dtype([(name, e + t) for name, t in props])
        if len(body) < n * dt.itemsize:
            raise ValueError(f"{path}: file is truncated ({len(body)} bytes of vertex data, "
                             f"expected {n * dt.itemsize})")
        rec = np.frombuffer(body, dtype=dt, count=n)
    names = [p for p, _ in props]
    for c in "xyz":
        if c not in names:
            raise ValueError(f"{path}: vertex property {c!r} missing")
    return {name: np.asarray(rec[name]) for name in names}
