"""Obstacle geoms of the trails: boxes, cylinders (upright trunks, fallen logs) and rocks.

An :class:`Obstacle` is one static convex MuJoCo geom. Besides its MuJoCo description (kind,
pos, quat, size, mesh) it offers the geometry the generator needs: world vertices, the
half-space form of its convex hull (to rasterise its top into the surface height map), its
footprint polygon and the signed horizontal distance of points to that footprint (goal
clearance, forest spacing). Cylinders are represented for these purposes by a circumscribed
16-gon prism, so footprints and tops are conservative (never smaller than the true geom).
Rocks are convex hulls of random points made with trimesh.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

__all__ = [
    "Obstacle",
    "OBSTACLE_KINDS",
    "make_box",
    "make_trunk",
    "make_log",
    "make_rock",
    "polygon_distance",
    "rasterise_tops",
]

OBSTACLE_KINDS = ("box", "cylinder", "rock")
_CYL_SECTIONS = 16


def _rot_z(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _mat_to_quat(r: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) -> unit quaternion (w, x, y, z) with w >= 0."""
    m = r
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.asarray(q, dtype=np.float64)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def _quat_to_mat(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def polygon_distance(poly: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Signed distance of points to a convex polygon (negative inside).

    Args:
        poly: (K, 2) vertices in counter-clockwise order.
        xy: (..., 2) points.

    Returns:
        (...,) signed Euclidean distance, metres.
    """
    xy = np.asarray(xy, dtype=np.float64)
    a = poly
    e = np.roll(poly, -1, axis=0) - a  # (K, 2)
    l2 = np.maximum(np.sum(e * e, axis=1), 1e-18)
    d = xy[..., None, :] - a  # (..., K, 2)
    t = np.clip(np.sum(d * e, axis=-1) / l2, 0.0, 1.0)
    diff = d - t[..., None] * e
    dist = np.sqrt(np.min(np.sum(diff * diff, axis=-1), axis=-1))
    cross = e[:, 0] * d[..., 1] - e[:, 1] * d[..., 0]
    inside = np.all(cross >= 0.0, axis=-1)
    return np.where(inside, -dist, dist)


@dataclass(eq=False)  # identity equality: fields hold numpy arrays
class Obstacle:
    """One static convex obstacle geom.

    Attributes:
        kind: "box", "cylinder" or "rock" (a mesh geom).
        pos: (3,) geom centre in the frame of its owner (patch, tile or world).
        quat: (4,) orientation (w, x, y, z).
        size: (3,) box half extents, or cylinder (radius, half length, 0); zeros for rocks.
        role: what it represents ("hurdle", "log", "tree", "rock", "boulder", "wall", "block").
        friction: sliding friction of the geom.
        embed: how deep its bottom sinks below the lowest ground under its footprint, metres.
        mesh_vertices: rocks only, (V, 3) hull vertices relative to ``pos``.
        mesh_faces: rocks only, (F, 3) triangle indices (outward normals).
    """

    kind: str
    pos: np.ndarray
    quat: np.ndarray
    size: np.ndarray
    role: str
    friction: float = 1.0
    embed: float = 0.0
    mesh_vertices: np.ndarray | None = field(default=None, repr=False)
    mesh_faces: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.kind not in OBSTACLE_KINDS:
            raise ValueError(
                f"unknown obstacle kind {self.kind!r}; valid kinds: {', '.join(OBSTACLE_KINDS)}"
            )
        self.pos = np.asarray(self.pos, dtype=np.float64).reshape(3)
        self.quat = np.asarray(self.quat, dtype=np.float64).reshape(4)
        self.size = np.asarray(self.size, dtype=np.float64).reshape(3)
        if self.kind == "rock" and (self.mesh_vertices is None or self.mesh_faces is None):
            raise ValueError("a rock obstacle needs mesh_vertices and mesh_faces")

    def translated(self, dx: float, dy: float, dz: float) -> Obstacle:
        """A copy moved by (dx, dy, dz)."""
        return dataclasses.replace(self, pos=self.pos + np.array([dx, dy, dz], dtype=np.float64))

    @cached_property
    def rotation(self) -> np.ndarray:
        """(3, 3) rotation matrix of ``quat``."""
        return _quat_to_mat(self.quat)

    @cached_property
    def local_vertices(self) -> np.ndarray:
        """(V, 3) vertices of the convex shape in the geom frame (cylinders: circumscribed prism)."""
        if self.kind == "box":
            sx, sy, sz = self.size
            c = np.array(
                [[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=np.float64
            )
            return c * np.array([sx, sy, sz])
        if self.kind == "cylinder":
            r, h = self.size[0], self.size[1]
            # half-step offset: flat faces at +-r along the local x and y axes
            ang = 2 * np.pi * (np.arange(_CYL_SECTIONS) + 0.5) / _CYL_SECTIONS
            rr = r / np.cos(np.pi / _CYL_SECTIONS)
            ring = np.stack([rr * np.cos(ang), rr * np.sin(ang)], axis=1)
            return np.concatenate(
                [np.c_[ring, np.full(len(ring), -h)], np.c_[ring, np.full(len(ring), h)]], axis=0
            )
        return np.asarray(self.mesh_vertices, dtype=np.float64)

    @cached_property
    def vertices(self) -> np.ndarray:
        """(V, 3) vertices in the owner frame."""
        return self.local_vertices @ self.rotation.T + self.pos

    @cached_property
    def planes(self) -> np.ndarray:
        """(F, 4) half-spaces ``n . p + c <= 0`` of the convex hull (unit outward normals n)."""
        return ConvexHull(self.vertices).equations

    @cached_property
    def footprint(self) -> np.ndarray:
        """(K, 2) counter-clockwise polygon: the horizontal projection of the hull."""
        xy = self.vertices[:, :2]
        hull = ConvexHull(xy)
        return xy[hull.vertices]

    @property
    def bottom(self) -> float:
        """Lowest z of the shape."""
        return float(self.vertices[:, 2].min())

    @property
    def top(self) -> float:
        """Highest z of the shape."""
        return float(self.vertices[:, 2].max())

    @cached_property
    def bounding_radius(self) -> float:
        """Largest horizontal distance of the footprint from ``pos``."""
        return float(np.max(np.linalg.norm(self.footprint - self.pos[:2], axis=1)))

    def footprint_distance(self, xy: np.ndarray) -> np.ndarray:
        """Signed horizontal distance (..., 2) -> (...,) of points to the footprint (< 0 inside)."""
        return polygon_distance(self.footprint, xy)

    @cached_property
    def _footprint_list(self) -> list[tuple[float, float]]:
        return [(float(a), float(b)) for a, b in self.footprint]

    def point_distance(self, x: float, y: float) -> float:
        """Signed distance of one point to the footprint (scalar fast path of footprint_distance)."""
        poly = self._footprint_list
        n = len(poly)
        best = math.inf
        inside = True
        for k in range(n):
            ax, ay = poly[k]
            bx, by = poly[(k + 1) % n]
            ex, ey = bx - ax, by - ay
            dx, dy = x - ax, y - ay
            l2 = ex * ex + ey * ey
            t = 0.0 if l2 <= 0 else min(1.0, max(0.0, (dx * ex + dy * ey) / l2))
            qx, qy = dx - t * ex, dy - t * ey
            best = min(best, qx * qx + qy * qy)
            if ex * dy - ey * dx < 0.0:
                inside = False
        d = math.sqrt(best)
        return -d if inside else d

    def top_at(self, xy: np.ndarray) -> np.ndarray:
        """Height of the top surface above points (..., 2) -> (...,); NaN outside the footprint."""
        xy = np.asarray(xy, dtype=np.float64)
        eq = self.planes
        n = eq[:, :3]
        a = xy[..., 0, None] * n[:, 0] + xy[..., 1, None] * n[:, 1] + eq[:, 3]  # (..., F)
        up = n[:, 2] > 1e-9
        down = n[:, 2] < -1e-9
        side = ~(up | down)
        z_top = np.min(-a[..., up] / n[up, 2], axis=-1)
        z_bot = (
            np.max(-a[..., down] / n[down, 2], axis=-1)
            if down.any()
            else np.full(z_top.shape, -np.inf)
        )
        ok = z_top >= z_bot - 1e-9
        if side.any():
            ok &= np.all(a[..., side] <= 1e-9, axis=-1)
        return np.where(ok, z_top, np.nan)


def make_box(
    center_xy: tuple[float, float],
    half_xy: tuple[float, float],
    height: float,
    yaw: float,
    role: str,
    friction: float,
    embed: float = 0.02,
) -> Obstacle:
    """A box standing on z = 0: ``height`` above the ground plus ``embed`` sunk into it."""
    hz = (height + embed) / 2.0
    return Obstacle(
        kind="box",
        pos=(center_xy[0], center_xy[1], hz - embed),
        quat=_mat_to_quat(_rot_z(yaw)),
        size=(half_xy[0], half_xy[1], hz),
        role=role,
        friction=friction,
        embed=embed,
    )


def make_trunk(
    center_xy: tuple[float, float],
    radius: float,
    height: float,
    role: str,
    friction: float,
    embed: float = 0.05,
) -> Obstacle:
    """An upright cylinder (tree trunk) standing on z = 0, ``height`` above the ground."""
    hz = (height + embed) / 2.0
    return Obstacle(
        kind="cylinder",
        pos=(center_xy[0], center_xy[1], hz - embed),
        quat=(1.0, 0.0, 0.0, 0.0),
        size=(radius, hz, 0.0),
        role=role,
        friction=friction,
        embed=embed,
    )


def make_log(
    center_xy: tuple[float, float],
    radius: float,
    length: float,
    yaw: float,
    role: str,
    friction: float,
    embed_fraction: float = 0.15,
) -> Obstacle:
    """A fallen log: horizontal cylinder along (-sin yaw, cos yaw, 0) (yaw=0: across the trail).

    Its axis is ``radius * (1 - embed_fraction)`` above the ground: the top is at
    ``radius * (2 - embed_fraction)``.
    """
    embed = embed_fraction * radius
    rx = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # z-axis -> +y
    r = _rot_z(yaw) @ rx
    return Obstacle(
        kind="cylinder",
        pos=(center_xy[0], center_xy[1], radius - embed),
        quat=_mat_to_quat(r),
        size=(radius, length / 2.0, 0.0),
        role=role,
        friction=friction,
        embed=embed,
    )


def make_rock(
    center_xy: tuple[float, float],
    radius_xy: tuple[float, float],
    height: float,
    yaw: float,
    rng: np.random.Generator,
    role: str,
    friction: float,
    bury_fraction: float = 0.25,
    num_points: int = 16,
) -> Obstacle:
    """A rock: trimesh convex hull of random points on a squashed sphere.

    Its top is ``height`` above the lowest ground under it; ``bury_fraction * height`` more is
    sunk into the ground.
    """
    u = rng.normal(size=(num_points, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    u *= rng.uniform(0.75, 1.0, size=(num_points, 1))
    embed = bury_fraction * height
    pts = np.stack([u[:, 0] * radius_xy[0], u[:, 1] * radius_xy[1], u[:, 2]], axis=1)
    pts[:, 2] = (pts[:, 2] - pts[:, 2].min()) / np.ptp(pts[:, 2]) * (height + embed)
    pts = pts @ _rot_z(yaw).T
    hull = trimesh.convex.convex_hull(pts)
    verts = np.asarray(hull.vertices, dtype=np.float64)
    return Obstacle(
        kind="rock",
        pos=(center_xy[0], center_xy[1], -embed),
        quat=(1.0, 0.0, 0.0, 0.0),
        size=(0.0, 0.0, 0.0),
        role=role,
        friction=friction,
        embed=embed,
        mesh_vertices=verts,
        mesh_faces=np.asarray(hull.faces, dtype=np.int64),
    )


def rasterise_tops(
    obstacles: list[Obstacle],
    surface: np.ndarray,
    origin: tuple[float, float],
    resolution: float,
    supersample: int = 3,
) -> np.ndarray:
    """Raise ``surface`` (in place) to the top of every obstacle over it.

    A sample takes the highest obstacle top found on a ``supersample x supersample`` lattice
    spanning its cell, so obstacles thinner than a cell are not missed.

    Args:
        obstacles: obstacles in the frame of the map.
        surface: (nx, ny) heights, sample (i, j) at ``origin + (i, j) * resolution``.
        origin: (x, y) of sample (0, 0).
        resolution: sample spacing, metres.
        supersample: sub-samples per cell side.

    Returns:
        (nx, ny) bool mask of the samples covered by an obstacle.
    """
    nx, ny = surface.shape
    covered = np.zeros(surface.shape, dtype=bool)
    off = (np.arange(supersample) - (supersample - 1) / 2.0) * resolution / supersample
    for ob in obstacles:
        v = ob.vertices
        i0 = max(int(np.floor((v[:, 0].min() - origin[0]) / resolution)) - 1, 0)
        i1 = min(int(np.ceil((v[:, 0].max() - origin[0]) / resolution)) + 2, nx)
        j0 = max(int(np.floor((v[:, 1].min() - origin[1]) / resolution)) - 1, 0)
        j1 = min(int(np.ceil((v[:, 1].max() - origin[1]) / resolution)) + 2, ny)
        if i0 >= i1 or j0 >= j1:
            continue
        xs = origin[0] + np.arange(i0, i1) * resolution
        ys = origin[1] + np.arange(j0, j1) * resolution
        px = xs[:, None, None, None] + off[None, None, :, None]
        py = ys[None, :, None, None] + off[None, None, None, :]
        px, py = np.broadcast_arrays(px, py)
        tops = ob.top_at(np.stack([px, py], axis=-1))  # (ni, nj, s, s)
        inside = ~np.isnan(tops)
        hit = inside.any(axis=(2, 3))
        if not hit.any():
            continue
        cell_top = np.where(hit, np.nanmax(np.where(inside, tops, -np.inf), axis=(2, 3)), -np.inf)
        block = surface[i0:i1, j0:j1]
        np.maximum(block, cell_top, out=block)
        covered[i0:i1, j0:j1] |= hit
    return covered
