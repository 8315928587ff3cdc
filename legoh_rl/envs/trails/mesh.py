"""Trails as triangle meshes (trimesh): view them, or load them into another simulator."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from .obstacles import Obstacle

__all__ = ["heightfield_mesh", "obstacle_mesh", "terrain_scene", "export_scene", "MESH_FORMATS"]

MESH_FORMATS = (".glb", ".obj", ".ply", ".stl")
_COLOURS = {
    "tree": (102, 66, 33, 255),
    "log": (115, 77, 38, 255),
    "hurdle": (204, 115, 38, 255),
    "rock": (128, 128, 128, 255),
    "boulder": (115, 115, 120, 255),
}


def heightfield_mesh(
    heights: np.ndarray, origin: tuple[float, float], resolution: float
) -> trimesh.Trimesh:
    """Triangulated surface of a height grid.

    Args:
        heights: (nx, ny) heights, sample (i, j) at ``origin + (i, j) * resolution``.
        origin: (x, y) of sample (0, 0).
        resolution: sample spacing, metres.

    Returns:
        Mesh with nx * ny vertices and 2 (nx - 1)(ny - 1) upward-facing triangles, coloured by
        height.
    """
    h = np.asarray(heights, dtype=np.float64)
    nx, ny = h.shape
    ii, jj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    verts = np.stack(
        [origin[0] + ii * resolution, origin[1] + jj * resolution, h], axis=-1
    ).reshape(-1, 3)
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)])
    span = max(float(h.max() - h.min()), 1e-6)
    t = ((h.ravel() - h.min()) / span)[:, None]
    low, high = np.array([70, 110, 60, 255.0]), np.array([200, 185, 150, 255.0])
    colours = (low * (1 - t) + high * t).astype(np.uint8)
    return trimesh.Trimesh(vertices=verts, faces=faces, vertex_colors=colours, process=False)


def obstacle_mesh(ob: Obstacle) -> trimesh.Trimesh:
    """The obstacle's shape as a mesh in its owner frame (cylinders with 24 sections)."""
    tf = np.eye(4)
    tf[:3, :3] = ob.rotation
    tf[:3, 3] = ob.pos
    if ob.kind == "box":
        m = trimesh.creation.box(extents=2.0 * ob.size, transform=tf)
    elif ob.kind == "cylinder":
        m = trimesh.creation.cylinder(
            radius=float(ob.size[0]), height=2.0 * float(ob.size[1]), sections=24, transform=tf
        )
    else:
        m = trimesh.Trimesh(
            vertices=np.asarray(ob.mesh_vertices) + ob.pos, faces=ob.mesh_faces, process=False
        )
    m.visual.face_colors = _COLOURS.get(ob.role, (140, 115, 90, 255))
    return m


def terrain_scene(
    heights: np.ndarray, origin: tuple[float, float], resolution: float, obstacles: list[Obstacle]
) -> trimesh.Scene:
    """Scene with geometry "terrain" (the height grid) and "obstacle_<k>" per obstacle."""
    scene = trimesh.Scene()
    scene.add_geometry(
        heightfield_mesh(heights, origin, resolution), geom_name="terrain", node_name="terrain"
    )
    for k, ob in enumerate(obstacles):
        name = f"obstacle_{k:04d}"
        scene.add_geometry(obstacle_mesh(ob), geom_name=name, node_name=name)
    return scene


def export_scene(scene: trimesh.Scene, path: str | Path) -> Path:
    """Write ``scene`` to ``path``; .glb keeps one node per geometry, .obj/.ply/.stl one mesh."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in MESH_FORMATS:
        raise ValueError(
            f"unsupported mesh format {p.suffix!r} for {str(p)!r}; valid: {', '.join(MESH_FORMATS)}"
        )
    p.parent.mkdir(parents=True, exist_ok=True)
    if suffix == ".glb":
        scene.export(str(p), file_type="glb")
    else:
        mesh = trimesh.util.concatenate(list(scene.dump()))
        mesh.export(str(p), file_type=suffix[1:])
    return p
