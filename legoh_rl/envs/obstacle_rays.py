"""Vectorised ray casting against static obstacle geoms (boxes, cylinders, convex meshes).

A drop-in for ``mj_ray`` / ``Batch.ray`` restricted to one geom group of static geoms that are
identical in every world: the geoms are read once from the compiled model, every (ray, geom) pair
is culled against the geom's bounding sphere (after a conservative pre-cull of blocks of
consecutive rays, so that no (rays x geoms) array is built when the rays are coherent), and only
the surviving pairs run the exact test. On the head camera's obstacle rays (64 worlds, 123
obstacles) this leaves ~1.6 candidate geoms per ray and is ~5x faster than ``Batch.ray``, which
tests every obstacle.
"""

from __future__ import annotations

import ctypes

import mujoco
import numpy as np

from legoh_rl.envs.native.build import load_library

__all__ = ["ObstacleRayCaster"]

_BOX = int(mujoco.mjtGeom.mjGEOM_BOX)
_CYLINDER = int(mujoco.mjtGeom.mjGEOM_CYLINDER)
_MESH = int(mujoco.mjtGeom.mjGEOM_MESH)
_SUPPORTED = {_BOX: "box", _CYLINDER: "cylinder", _MESH: "mesh"}

# (ray, geom) pairs per culling chunk at most: bounds the temporaries to a few hundred MB
_CHUNK_PAIRS = 1 << 20
# consecutive rays per block of the coarse cull (see ObstacleRayCaster.candidates)
_BLOCK = 32


class ObstacleRayCaster:
    """First hits of rays on a fixed set of static geoms, vectorised over rays and geoms.

    Follows ``mujoco.mj_ray``'s conventions: a ray is ``o + t d`` with ``t >= 0`` in units of
    ``|d|`` (``d`` need not be unit), the result is the distance to the nearest geom *surface*
    crossed at ``t >= 0``, so a ray starting inside a geom reports where it leaves it (as
    ``mj_ray`` does for boxes, cylinders and convex meshes), and invisible geoms (alpha 0) are
    skipped. Meshes are treated as convex polytopes (the intersection of their faces'
    half-spaces); :meth:`from_model` rejects meshes that are not convex.

    Attributes:
        block: consecutive rays that share the coarse cull of :meth:`candidates` (a cost knob:
            results never depend on it).

    Args:
        geom_ids: (G,) model geom ids (for messages and reference).
        geom_type: (G,) ``mjtGeom`` type of each geom (box, cylinder or mesh).
        pos: (G, 3) geom frame origins in the world.
        mat: (G, 3, 3) geom frame rotations (columns = geom axes in world).
        size: (G, 3) MuJoCo ``geom_size`` (box half-sizes; cylinder radius, half-length).
        rbound: (G,) bounding sphere radius about ``pos`` of each geom.
        mesh_planes: list of G entries, for meshes a (F, 4) array of face planes
            ``n . x <= h`` as rows ``(n_x, n_y, n_z, h)`` in the geom frame (outward unit
            normals), ``None`` for the other types.
    """

    def __init__(
        self,
        geom_ids: np.ndarray,
        geom_type: np.ndarray,
        pos: np.ndarray,
        mat: np.ndarray,
        size: np.ndarray,
        rbound: np.ndarray,
        mesh_planes: list[np.ndarray | None],
    ) -> None:
        self.geom_ids = np.asarray(geom_ids, dtype=np.int64).reshape(-1)
        self.geom_type = np.asarray(geom_type, dtype=np.int64).reshape(-1)
        G = self.geom_ids.size
        self.pos = np.asarray(pos, dtype=np.float64).reshape(G, 3)
        self.mat = np.asarray(mat, dtype=np.float64).reshape(G, 3, 3)
        self.size = np.asarray(size, dtype=np.float64).reshape(G, 3)
        self.rbound = np.asarray(rbound, dtype=np.float64).reshape(G)
        if len(mesh_planes) != G:
            raise ValueError(f"mesh_planes needs one entry per geom ({G}), got {len(mesh_planes)}")
        for i, t in enumerate(self.geom_type):
            if int(t) not in _SUPPORTED:
                raise ValueError(f"geom {self.geom_ids[i]}: unsupported geom type {_type_name(t)} "
                                 f"(supported: {', '.join(_SUPPORTED.values())})")
            if int(t) == _MESH and mesh_planes[i] is None:
                raise ValueError(f"geom {self.geom_ids[i]}: a mesh needs its face planes")
        self.block = _BLOCK
        self._pos_c, self._mat_c, self._size_c = (np.ascontiguousarray(a) for a in (self.pos, self.mat, self.size))
        self._size_t = np.ascontiguousarray(self.size.T)  # (3, G)
        # bounding spheres, padded a little so that rounding never culls a true hit
        self._r2 = (self.rbound * (1.0 + 1e-9) + 1e-9) ** 2
        # mesh planes padded to a common count with always-satisfied planes (n = 0, h = 1)
        is_mesh = self.geom_type == _MESH
        self._mesh_index = np.full(G, -1, dtype=np.int64)
        self._mesh_index[is_mesh] = np.arange(int(is_mesh.sum()))
        planes = [np.asarray(mesh_planes[i], dtype=np.float64).reshape(-1, 4) for i in np.flatnonzero(is_mesh)]
        f_max = max((p.shape[0] for p in planes), default=1)
        self._planes = np.zeros((len(planes), f_max, 4))
        self._planes[..., 3] = 1.0
        for k, p in enumerate(planes):
            self._planes[k, : p.shape[0]] = p
        #: use the native kernel (legoh_rl.envs.native) in :meth:`cast` when it is available
        self.native = True
        # the native kernel's flat layout: kind codes, and every mesh's planes in one (F, 4) array
        self._kind = np.select([self.geom_type == _BOX, self.geom_type == _CYLINDER], [0, 1], 2).astype(np.int32)
        counts = np.array([0 if p is None else np.asarray(p).reshape(-1, 4).shape[0] for p in mesh_planes], np.int64)
        self._plane_start = (np.cumsum(counts) - counts).astype(np.int64)
        self._plane_count = counts
        self._flat_planes = np.ascontiguousarray(
            np.concatenate([np.asarray(p, np.float64).reshape(-1, 4) for p in mesh_planes if p is not None]
                           or [np.zeros((1, 4))]))

    @property
    def num_geoms(self) -> int:
        """Number of geoms the caster tests."""
        return int(self.geom_ids.size)

    @classmethod
    def from_model(cls, model: mujoco.MjModel, group: int = 1) -> ObstacleRayCaster:
        """The caster of every visible geom in geom group ``group`` of a compiled model.

        Geom poses are taken after one ``mj_forward`` on a fresh ``MjData`` (the geoms must be
        static, i.e. welded to the world body, so that these poses hold in every world and state).
        Mesh vertices (``mesh_vert``) are stored by MuJoCo in the geom frame (the compiler moves
        the mesh to its inertial frame and folds that offset into the geom pose), so they map to
        the world by ``geom_xpos + geom_xmat @ v``, exactly as ``mj_ray`` does.

        Args:
            model: the compiled model.
            group: the geom group to cast against (0..5).

        Returns:
            the caster.

        Raises:
            ValueError: for a geom of an unsupported type (anything but box, cylinder, mesh), a
                geom on a moving body, or a mesh that is not convex.
        """
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        sel = np.flatnonzero(model.geom_group == group)
        # mj_ray skips invisible geoms: alpha 0 of the geom (no material) or of its material
        matid = model.geom_matid[sel]
        alpha = model.geom_rgba[sel, 3].copy()
        alpha[matid >= 0] = model.mat_rgba[matid[matid >= 0], 3]
        sel = sel[alpha != 0]
        types = model.geom_type[sel].astype(np.int64)
        for g, t in zip(sel, types, strict=True):
            if int(t) not in _SUPPORTED:
                raise ValueError(f"geom {g} ({_geom_name(model, g)}): unsupported geom type {_type_name(t)} "
                                 f"(supported: {', '.join(_SUPPORTED.values())})")
            if model.body_weldid[model.geom_bodyid[g]] != 0:
                raise ValueError(f"geom {g} ({_geom_name(model, g)}) is not static: its body moves")
        size = model.geom_size[sel].astype(np.float64)
        rbound = np.zeros(sel.size)
        planes: list[np.ndarray | None] = [None] * sel.size
        for j, (g, t) in enumerate(zip(sel, types, strict=True)):
            if t == _BOX:
                rbound[j] = np.linalg.norm(size[j])
            elif t == _CYLINDER:
                rbound[j] = np.hypot(size[j, 0], size[j, 1])
            else:
                verts, faces = _mesh_arrays(model, int(model.geom_dataid[g]))
                rbound[j] = np.sqrt((verts**2).sum(axis=1).max())
                planes[j] = _convex_planes(verts, faces, f"geom {g} ({_geom_name(model, g)})")
        return cls(sel, types, data.geom_xpos[sel].copy(), data.geom_xmat[sel].reshape(-1, 3, 3).copy(),
                   size, rbound, planes)

    def cast(self, origins: np.ndarray, dirs: np.ndarray, t_max: np.ndarray, threads: int = 1) -> np.ndarray:
        """Distance along each ray to the first geom surface in ``[0, t_max]``.

        With the native kernel (:mod:`legoh_rl.envs.native`, when it builds and :attr:`native` is
        True) the same tests run in C on ``threads`` threads; else in numpy (one thread).

        Args:
            origins: (M, 3) ray origins.
            dirs: (M, 3) ray directions (distances are in units of their length, as ``mj_ray``).
            t_max: (M,) longest distance to look along each ray.
            threads: threads for the native kernel.

        Returns:
            (M,) float64 distances, ``inf`` where a ray meets no geom within ``t_max``.
        """
        o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        M = o.shape[0]
        tm = np.broadcast_to(np.asarray(t_max, dtype=np.float64), (M,))
        if d.shape[0] != M:
            raise ValueError(f"origins and dirs must have the same length, got {M} and {d.shape[0]}")
        out = np.full(M, np.inf)
        if M == 0 or self.num_geoms == 0:
            return out
        lib = load_library() if self.native else None
        if lib is not None:
            return self._cast_native(lib, o, d, tm, out, threads)
        rays, geoms = self.candidates(o, d, tm)
        if rays.size == 0:
            return out
        # the rays in each candidate geom's frame, (3, P): one contiguous row per axis
        # (np.take: row gathers 4x faster than a[idx])
        R = np.take(self.mat, geoms, axis=0)  # (P, 3, 3)
        lo = np.einsum("pi,pij->jp", np.take(o, rays, axis=0) - np.take(self.pos, geoms, axis=0), R)
        ld = np.einsum("pi,pij->jp", np.take(d, rays, axis=0), R)
        t = np.full(rays.size, np.inf)
        kinds = self.geom_type[geoms]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            for kind, fn in ((_BOX, self._box), (_CYLINDER, self._cylinder), (_MESH, self._mesh)):
                k = np.flatnonzero(kinds == kind)
                if k.size:
                    t[k] = fn(np.take(lo, k, axis=1), np.take(ld, k, axis=1), geoms[k])
        ok = t <= tm[rays]
        np.minimum.at(out, rays[ok], t[ok])
        return out

    def native_geometry(self) -> tuple:
        """The geoms in the native kernels' layout: ``(G, kind, pos, mat, size, r2, plane_start,
        plane_count, planes)``, counts as ints and arrays as addresses (``lh_obstacle_cast``'s and
        the fused camera's arguments; the arrays live as long as this caster)."""
        arrays = (self._kind, self._pos_c, self._mat_c, self._size_c, self._r2, self._plane_start, self._plane_count,
                  self._flat_planes)
        return (self.num_geoms, *(a.ctypes.data for a in arrays))

    def _cast_native(self, lib, o, d, tm, out, threads: int) -> np.ndarray:
        o, d, tm = (np.ascontiguousarray(a, dtype=np.float64) for a in (o, d, tm))
        f64, i64 = ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_int64)

        def ptr(a, t=f64):
            return a.ctypes.data_as(t)

        # returns -1 only when a thread failed to start; the result is complete either way
        lib.lh_obstacle_cast(self.num_geoms, self._kind.ctypes.data_as(ctypes.POINTER(ctypes.c_int32)),
                             ptr(self._pos_c), ptr(self._mat_c), ptr(self._size_c), ptr(self._r2),
                             ptr(self._plane_start, i64), ptr(self._plane_count, i64), ptr(self._flat_planes),
                             o.shape[0], ptr(o), ptr(d), ptr(tm), ptr(out), int(threads))
        return out

    def candidates(self, origins: np.ndarray, dirs: np.ndarray, t_max: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ray, geom) pairs whose segment ``[0, t_max]`` meets the geom's bounding sphere.

        Two stages, both vectorised: consecutive rays are taken in blocks of :attr:`block` and each
        geom's bounding sphere is tested against the axis-aligned box of a block's segments (a
        cheap (M / block, G) test that drops most pairs when neighbouring rays are coherent, as a
        camera's are); the pairs that survive are expanded (compaction, no (M, G) array) and
        tested exactly against the sphere: the closest point of the segment to the centre. The
        result does not depend on the ray order, only the cost does. Rays are processed in chunks
        so that the temporaries stay bounded.

        Args:
            origins: (M, 3) ray origins.
            dirs: (M, 3) ray directions.
            t_max: (M,) segment lengths (in units of ``|dirs|``; may be ``inf``).

        Returns:
            rays (P,), geoms (P,): indices of the surviving pairs (geoms index this caster's
            geoms, not the model's), sorted by ray.
        """
        o = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        d = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
        M, G, B = o.shape[0], self.num_geoms, self.block
        tm = np.broadcast_to(np.asarray(t_max, dtype=np.float64), (M,))
        if M == 0 or G == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        with np.errstate(invalid="ignore", over="ignore"):
            end = np.where(d == 0.0, o, o + d * tm[:, None])  # no 0 * inf
        dd = np.maximum(np.einsum("mi,mi->m", d, d), 1e-300)
        step = max(1, _CHUNK_PAIRS // G // B) * B
        rays, geoms = [], []
        for s in range(0, M, step):
            e = min(M, s + step)
            # 1) blocks of B rays: the segments' bounding box against each bounding sphere
            starts = np.arange(s, e, B)
            lo = np.minimum.reduceat(np.minimum(o[s:e], end[s:e]), starts - s, axis=0)
            hi = np.maximum.reduceat(np.maximum(o[s:e], end[s:e]), starts - s, axis=0)
            dist2 = np.zeros((starts.size, G))
            for i in range(3):  # distance of the centre from the box, one axis at a time
                c = self.pos[None, :, i]
                gap = np.maximum(np.maximum(lo[:, i, None] - c, c - hi[:, i, None]), 0.0)
                dist2 += gap * gap
            kk, gg = np.nonzero(dist2 <= self._r2[None])
            # expand: every ray of block k with every geom that survived for k
            per_block = np.bincount(kk, minlength=starts.size)
            first = np.cumsum(per_block) - per_block  # where block k's geoms start in gg
            blk = np.arange(e - s) // B
            cnt = per_block[blk]
            r = np.repeat(np.arange(s, e), cnt)
            offs = np.cumsum(cnt) - cnt
            g = gg[np.arange(r.size) - np.repeat(offs - first[blk], cnt)]
            # 2) each pair: the segment's closest point to the centre, t* = clip(b / |d|^2, 0, t_max)
            dr = np.take(d, r, axis=0)
            oc = np.take(self.pos, g, axis=0) - np.take(o, r, axis=0)
            ts = np.einsum("pi,pi->p", oc, dr) / dd[r]
            np.minimum(np.maximum(ts, 0.0, out=ts), tm[r], out=ts)
            oc -= ts[:, None] * dr
            keep = np.einsum("pi,pi->p", oc, oc) <= self._r2[g]
            rays.append(r[keep])
            geoms.append(g[keep])
        return np.concatenate(rays), np.concatenate(geoms)

    def _box(self, lo: np.ndarray, ld: np.ndarray, geoms: np.ndarray) -> np.ndarray:
        """Slab test in the box frame: (3, P), (3, P), (P,) -> (P,) distance or ``inf``."""
        size = np.take(self._size_t, geoms, axis=1)
        t_lo = np.full(geoms.size, -np.inf)
        t_hi = np.full(geoms.size, np.inf)
        for i in range(3):
            s, o, d = size[i], lo[i], ld[i]
            inv = 1.0 / d
            t1 = (-s - o) * inv
            t2 = (s - o) * inv
            par = d == 0.0  # parallel to the slab: inside it for all t, or never
            outside = par & (np.abs(o) > s)
            np.maximum(t_lo, np.where(par, -np.inf, np.minimum(t1, t2)), out=t_lo)
            np.minimum(t_hi, np.where(par, np.inf, np.maximum(t1, t2)), out=t_hi)
            t_hi[outside] = -np.inf
        return _entry_or_exit(t_lo, t_hi)

    def _cylinder(self, lo: np.ndarray, ld: np.ndarray, geoms: np.ndarray) -> np.ndarray:
        """Side (quadratic) and caps of a z-axis cylinder: (3, P), (3, P), (P,) -> (P,)."""
        r, h = np.take(self._size_t[0], geoms), np.take(self._size_t[1], geoms)
        (ox, oy, oz), (dx, dy, dz) = lo, ld
        a = dx * dx + dy * dy
        b = ox * dx + oy * dy
        c = ox * ox + oy * oy - r * r
        disc = b * b - a * c
        q = -(b + np.copysign(np.sqrt(np.maximum(disc, 0.0)), b))  # stable roots: q / a and c / q
        side = (disc >= 0.0) & (a > 0.0)
        best = np.full(geoms.size, np.inf)
        for root in (q / a, c / q):
            ok = side & (root >= 0.0) & (np.abs(oz + root * dz) <= h)
            best = np.where(ok & (root < best), root, best)
        for sign in (-1.0, 1.0):
            tc = (sign * h - oz) / dz
            x = ox + tc * dx
            y = oy + tc * dy
            ok = (dz != 0.0) & (tc >= 0.0) & (x * x + y * y <= r * r)
            best = np.where(ok & (tc < best), tc, best)
        return best

    def _mesh(self, lo: np.ndarray, ld: np.ndarray, geoms: np.ndarray) -> np.ndarray:
        """Convex polytope (intersection of face half-spaces): (3, P), (3, P), (P,) -> (P,)."""
        planes = np.take(self._planes, self._mesh_index[geoms], axis=0)  # (P, F, 4)
        n, h = planes[..., :3], planes[..., 3]
        denom = np.einsum("pfi,ip->pf", n, ld)
        num = h - np.einsum("pfi,ip->pf", n, lo)  # >= 0: origin inside that half-space
        t = num / denom
        t_lo = np.where(denom < 0.0, t, -np.inf).max(axis=1)  # entering planes
        t_hi = np.where(denom > 0.0, t, np.inf).min(axis=1)  # leaving planes
        outside_parallel = ((denom == 0.0) & (num < 0.0)).any(axis=1)
        return np.where(outside_parallel, np.inf, _entry_or_exit(t_lo, t_hi))


def _entry_or_exit(t_lo: np.ndarray, t_hi: np.ndarray) -> np.ndarray:
    """Nearest surface crossing at t >= 0 of a convex interval ``[t_lo, t_hi]`` (inf if none)."""
    hit = (t_lo <= t_hi) & (t_hi >= 0.0)
    return np.where(hit, np.where(t_lo >= 0.0, t_lo, t_hi), np.inf)


def _mesh_arrays(model: mujoco.MjModel, mesh: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 in the geom frame and faces (F, 3) local vertex indices of a mesh."""
    va, vn = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
    fa, fn = int(model.mesh_faceadr[mesh]), int(model.mesh_facenum[mesh])
    return model.mesh_vert[va : va + vn].astype(np.float64), model.mesh_face[fa : fa + fn].astype(np.int64)


def _convex_planes(verts: np.ndarray, faces: np.ndarray, what: str) -> np.ndarray:
    """Outward face planes (F', 4) rows ``(n, h)`` of a convex mesh, coplanar faces merged.

    Raises ValueError when a vertex lies outside a face plane by more than 1e-6 of the mesh size
    (the mesh is not convex, and a plane test would see its convex hull instead).
    """
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    n = np.cross(b - a, c - a)
    norm = np.linalg.norm(n, axis=1)
    scale = np.abs(verts).max()
    keep = norm > 1e-12 * max(scale, 1e-12) ** 2  # drop degenerate triangles
    n = n[keep] / norm[keep, None]
    h = np.einsum("fi,fi->f", n, a[keep])
    # orient outwards: the vertex centroid lies inside a convex polytope
    centre = verts.mean(axis=0)
    flip = n @ centre > h
    n[flip], h[flip] = -n[flip], -h[flip]
    if n.shape[0] < 4:
        raise ValueError(f"{what}: mesh has fewer than 4 non-degenerate faces")
    excess = (verts @ n.T - h[None, :]).max()
    if excess > 1e-6 * scale:
        raise ValueError(f"{what}: mesh is not convex (a vertex lies {excess:.3g} outside a face plane)")
    planes = np.concatenate([n, h[:, None]], axis=1)
    # merge coplanar faces (a convex hull's quads and polygons are split into triangles)
    key = np.concatenate([n, h[:, None] / max(scale, 1e-12)], axis=1)
    _, first = np.unique(np.round(key, 9), axis=0, return_index=True)
    return planes[np.sort(first)]


def _type_name(t) -> str:
    try:
        return mujoco.mjtGeom(int(t)).name.removeprefix("mjGEOM_").lower()
    except ValueError:
        return str(int(t))


def _geom_name(model: mujoco.MjModel, g: int) -> str:
    return mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, int(g)) or "unnamed"
