"""A MuJoCo model's geoms as triangle meshes, and their world poses in batched worlds.

Viewers that draw triangle meshes (the browser viewer, :mod:`legoh_rl.viewer.web`) show exactly
what the simulation collides with and MuJoCo's own viewer draws: every geom is read from the
compiled ``mujoco.MjModel`` (its type, ``geom_size``, mesh and heightfield data, colour), not
modelled again by hand.

* :func:`geom_mesh` gives one geom's triangles in the geom's own frame: a mesh geom's compiled
  vertices, a heightfield's grid of samples, and MuJoCo's primitives (box, sphere, capsule,
  cylinder, ellipsoid, plane) tessellated at their ``geom_size``.
* :func:`geom_world_poses` places geoms of moving bodies in every world from the worlds' body
  poses (``xpos``/``xquat``, (N, nbody, ...)), which both physics backends keep on the host, so
  no per-world ``MjData`` copy is needed.
* :func:`static_geoms` and :func:`robot_geoms` pick the terrain's and the robot's geoms;
  :func:`simplify_mesh` lightens a dense mesh for display.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

__all__ = [
    "GeomMesh",
    "geom_mesh",
    "geom_rgba",
    "geom_world_poses",
    "mesh_of",
    "quat_multiply",
    "quat_rotate",
    "robot_geoms",
    "simplify_mesh",
    "static_geoms",
]

#: tessellation of MuJoCo's round primitives (segments around, icosphere subdivisions)
_SECTIONS = 20
_SUBDIVISIONS = 2
#: half-size of an infinite plane (MuJoCo's ``size`` 0), m
_PLANE_HALF = 50.0


@dataclass(frozen=True)
class GeomMesh:
    """One geom as triangles in its own frame.

    Attributes:
        geom: the geom's id in the model.
        name: its name (``geom_<id>`` when unnamed).
        vertices: (V, 3) float32, the geom's frame.
        faces: (F, 3) int32 vertex indices, counter-clockwise seen from outside.
        rgba: (4,) float in [0, 1]: the geom's material colour, or its own ``geom_rgba``.
        body: the body the geom belongs to (0: the world, i.e. static).
        kind: the MuJoCo geom type's name (``"mesh"``, ``"hfield"``, ``"box"``, ...).
    """

    geom: int
    name: str
    vertices: np.ndarray
    faces: np.ndarray
    rgba: np.ndarray
    body: int
    kind: str


def geom_rgba(model: mujoco.MjModel, geom: int) -> np.ndarray:
    """(4,) colour MuJoCo draws geom ``geom`` in: its material's ``mat_rgba`` when it has a
    material, else its ``geom_rgba``."""
    mat = int(model.geom_matid[geom])
    return np.array(model.mat_rgba[mat] if mat >= 0 else model.geom_rgba[geom], dtype=np.float64)


def geom_mesh(model: mujoco.MjModel, geom: int) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of geom ``geom`` in its own frame: ``(vertices (V, 3) float32, faces (F, 3) int32)``.

    Raises:
        ValueError: ``geom`` is not a geom id of ``model``, or its type has no surface here
            (``mjGEOM_SDF`` and other user types); the message names the geom and its type.
    """
    if not 0 <= int(geom) < model.ngeom:
        raise ValueError(f"geom id {geom} is out of range [0, {model.ngeom})")
    g = int(geom)
    kind = mujoco.mjtGeom(int(model.geom_type[g]))
    size = np.asarray(model.geom_size[g], dtype=np.float64)
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        return mesh_of(model, int(model.geom_dataid[g]))
    if kind == mujoco.mjtGeom.mjGEOM_HFIELD:
        return _hfield(model, int(model.geom_dataid[g]))
    import trimesh.creation as tc  # a dependency of the package (trail exports)

    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        mesh = tc.box(extents=2.0 * size)
    elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        mesh = tc.icosphere(subdivisions=_SUBDIVISIONS, radius=size[0])
    elif kind == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        mesh = tc.icosphere(subdivisions=_SUBDIVISIONS, radius=1.0)
        mesh.vertices = mesh.vertices * size[None, :3]
    elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:  # size: radius, half-length of the cylinder part
        mesh = tc.capsule(height=2.0 * size[1], radius=size[0], count=[_SECTIONS, _SECTIONS])
    elif kind == mujoco.mjtGeom.mjGEOM_CYLINDER:  # size: radius, half-height
        mesh = tc.cylinder(radius=size[0], height=2.0 * size[1], sections=_SECTIONS)
    elif kind == mujoco.mjtGeom.mjGEOM_PLANE:
        hx = size[0] if size[0] > 0 else _PLANE_HALF
        hy = size[1] if size[1] > 0 else _PLANE_HALF
        vertices = np.array([[-hx, -hy, 0.0], [hx, -hy, 0.0], [hx, hy, 0.0], [-hx, hy, 0.0]], dtype=np.float32)
        return vertices, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32)
    else:
        raise ValueError(f"geom {g} ({model.geom(g).name or 'unnamed'}) has type {kind.name}, which has no "
                         "triangle surface here")
    return np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.faces, dtype=np.int32)


def mesh_of(model: mujoco.MjModel, mesh: int) -> tuple[np.ndarray, np.ndarray]:
    """The compiled vertices (V, 3) float32 and faces (F, 3) int32 of mesh asset ``mesh`` (in the
    frame of the geoms that use it: MuJoCo re-centres meshes when it compiles them)."""
    v0, nv = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
    f0, nf = int(model.mesh_faceadr[mesh]), int(model.mesh_facenum[mesh])
    return (np.array(model.mesh_vert[v0:v0 + nv], dtype=np.float32),
            np.array(model.mesh_face[f0:f0 + nf], dtype=np.int32))


def _hfield(model: mujoco.MjModel, hfield: int) -> tuple[np.ndarray, np.ndarray]:
    """The top surface of heightfield ``hfield``: one vertex per sample, two triangles per cell.

    MuJoCo's layout: ``nrow`` rows along y, ``ncol`` columns along x, spanning
    ``[-size[0], size[0]] x [-size[1], size[1]]``; sample heights are ``data * size[2]``.
    """
    nrow, ncol = int(model.hfield_nrow[hfield]), int(model.hfield_ncol[hfield])
    sx, sy, sz = (float(v) for v in model.hfield_size[hfield][:3])
    adr = int(model.hfield_adr[hfield])
    z = np.asarray(model.hfield_data[adr:adr + nrow * ncol], dtype=np.float64).reshape(nrow, ncol) * sz
    x = np.linspace(-sx, sx, ncol)
    y = np.linspace(-sy, sy, nrow)
    xx, yy = np.meshgrid(x, y)  # (nrow, ncol): rows along y
    vertices = np.stack([xx, yy, z], axis=-1).reshape(-1, 3).astype(np.float32)
    idx = np.arange(nrow * ncol).reshape(nrow, ncol)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()  # (r, c), (r, c + 1)
    c, d = idx[1:, 1:].ravel(), idx[1:, :-1].ravel()  # (r + 1, c + 1), (r + 1, c)
    faces = np.concatenate([np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)]).astype(np.int32)
    return vertices, faces


def simplify_mesh(vertices: np.ndarray, faces: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """A lighter copy of a triangle mesh for display (vertex clustering): vertices in the same
    ``cell``-metre grid cell merge into their mean, and triangles that collapse (two corners in
    one cell) or repeat another are dropped; the rest keep their winding.

    Detail finer than ``cell`` goes; a robot's scanned meshes shrink several times at 5 mm with
    no visible change at viewing distance. Returns ``(vertices (V', 3) float32, faces (F', 3) int32)``.

    Raises:
        ValueError: ``cell`` is not a positive length.
    """
    if not (np.isfinite(cell) and cell > 0.0):
        raise ValueError(f"cell must be a positive length in metres, got {cell!r}")
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0:
        return v.astype(np.float32), f.astype(np.int32)
    _, cluster, counts = np.unique(np.floor(v / cell).astype(np.int64), axis=0, return_inverse=True,
                                   return_counts=True)
    cluster = cluster.reshape(-1)
    merged = np.zeros((counts.size, 3))
    np.add.at(merged, cluster, v)
    merged /= counts[:, None]
    tri = cluster[f]
    tri = tri[(tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])]
    _, first = np.unique(np.sort(tri, axis=1), axis=0, return_index=True)
    tri = tri[np.sort(first)]
    used, tri = np.unique(tri, return_inverse=True)  # drop the vertices no triangle uses
    return merged[used].astype(np.float32), tri.reshape(-1, 3).astype(np.int32)


def _geom_mesh_record(model: mujoco.MjModel, g: int) -> GeomMesh:
    vertices, faces = geom_mesh(model, g)
    return GeomMesh(geom=g, name=model.geom(g).name or f"geom_{g}", vertices=vertices, faces=faces,
                    rgba=geom_rgba(model, g), body=int(model.geom_bodyid[g]),
                    kind=mujoco.mjtGeom(int(model.geom_type[g])).name.removeprefix("mjGEOM_").lower())


def static_geoms(model: mujoco.MjModel) -> list[tuple[GeomMesh, np.ndarray, np.ndarray]]:
    """The geoms of the world body (the terrain's heightfield and obstacles), each with its world
    position (3,) and quaternion (4,) (w, x, y, z): ``[(mesh, pos, quat), ...]``."""
    out = []
    for g in np.flatnonzero(model.geom_bodyid == 0):
        out.append((_geom_mesh_record(model, int(g)), np.array(model.geom_pos[g]), np.array(model.geom_quat[g])))
    return out


def robot_geoms(model: mujoco.MjModel, group: int | None = None) -> list[GeomMesh]:
    """The geoms of the moving bodies (the robot), in their own frames.

    Args:
        group: keep only the geoms of this geom group (the robot's visual meshes:
            ``legoh_rl.envs.robots.ROBOT_GEOM_GROUPS[0]``); every moving geom when ``None``, or
            when no geom is in ``group``.
    """
    moving = np.flatnonzero(model.geom_bodyid != 0)
    if group is not None:
        visual = moving[model.geom_group[moving] == int(group)]
        moving = visual if visual.size else moving
    return [_geom_mesh_record(model, int(g)) for g in moving]


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products ``a * b`` of (..., 4) (w, x, y, z) quaternions (broadcast)."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors (..., 3) rotated by unit quaternions (..., 4) (w, x, y, z) (broadcast)."""
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def geom_world_poses(model: mujoco.MjModel, geoms, xpos: np.ndarray, xquat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World poses of geoms in every world, from the worlds' body poses.

    Args:
        model: the model (its ``geom_bodyid``, ``geom_pos``, ``geom_quat``: the geoms' fixed poses
            in their bodies).
        geoms: (G,) geom ids.
        xpos: (N, nbody, 3) body positions of N worlds.
        xquat: (N, nbody, 4) body orientations (w, x, y, z).

    Returns:
        ``(pos (N, G, 3), quat (N, G, 4))``: what ``MjData.geom_xpos``/``geom_xmat`` hold after
        ``mj_kinematics``, as quaternions.
    """
    geoms = np.asarray(geoms, dtype=np.int64).reshape(-1)
    bodies = model.geom_bodyid[geoms]
    bpos, bquat = np.asarray(xpos)[:, bodies], np.asarray(xquat)[:, bodies]  # (N, G, ...)
    pos = bpos + quat_rotate(bquat, model.geom_pos[geoms][None])
    quat = quat_multiply(bquat, model.geom_quat[geoms][None])
    return pos, quat / np.linalg.norm(quat, axis=-1, keepdims=True)
