"""Batched sensors: head depth camera (ray casting), scandots, contacts, base state.

All functions take ``(N, ...)`` arrays and loop over no world in Python.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

from legoh_rl.envs.robots import TERRAIN_GEOM_GROUPS

__all__ = [
    "DepthCameraConfig",
    "DepthCamera",
    "scandot_offsets",
    "scandots",
    "quat_to_rotmat",
    "yaw_from_quat",
    "roll_pitch_from_gravity",
    "world_to_yaw_frame",
]


@dataclass
class DepthCameraConfig:
    """Head depth camera.

    Attributes:
        height, width: image size in pixels (64x64 default, 128x128 paper).
        near, far: clipping range, m. Depth is the z-depth (distance along the optical axis, as a
            real depth camera reports), clipped to [near, far] and normalised to [0, 1];
            rays that hit nothing read ``far`` (1.0).
        noise_std: std of additive Gaussian noise on the normalised depth (0 = off).
        dropout: probability that a pixel reads 0 (missing return, as a stereo camera's holes).
    """

    height: int = 64
    width: int = 64
    near: float = 0.2
    far: float = 4.0
    noise_std: float = 0.0
    dropout: float = 0.0

    def __post_init__(self) -> None:
        if self.height < 1 or self.width < 1:
            raise ValueError(f"depth resolution must be positive, got {self.height}x{self.width}")
        if not 0.0 <= self.near < self.far:
            raise ValueError(f"need 0 <= near < far, got near={self.near}, far={self.far}")


class DepthCamera:
    """Renders the head depth camera of many worlds with one ``Batch.ray`` call.

    Rays see only geoms of the terrain groups (0 and 1), so the robot's own body never
    occludes the view.

    Args:
        cfg: the camera configuration.
        fovy_deg: vertical field of view (the model camera's ``fovy``); the image is square in
            angle when height == width.
    """

    def __init__(self, cfg: DepthCameraConfig, fovy_deg: float) -> None:
        self.cfg = cfg
        tan_y = math.tan(math.radians(fovy_deg) / 2.0)
        tan_x = tan_y * cfg.width / cfg.height
        # pixel centres; row 0 is the top of the image, column 0 the left
        v = (1.0 - (np.arange(cfg.height) + 0.5) / cfg.height * 2.0) * tan_y
        u = ((np.arange(cfg.width) + 0.5) / cfg.width * 2.0 - 1.0) * tan_x
        uu, vv = np.meshgrid(u, v)
        dirs = np.stack([uu, vv, -np.ones_like(uu)], axis=-1).reshape(-1, 3)  # camera frame
        self._axis_cos = 1.0 / np.linalg.norm(dirs, axis=1)  # cos(angle to the optical axis)
        self._dirs_cam = dirs * self._axis_cos[:, None]  # unit rays
        self._groups = np.zeros(mujoco.mjNGROUP, dtype=np.uint8)
        self._groups[list(TERRAIN_GEOM_GROUPS)] = 1

    def render(
        self,
        batch,
        cam_pos: np.ndarray,
        cam_mat: np.ndarray,
        ids: np.ndarray,
        rng: np.random.Generator | None = None,
    ) -> np.ndarray:
        """Depth images of worlds ``ids``.

        Args:
            batch: the ``mujoco.batch.Batch`` of the worlds.
            cam_pos: camera positions of those worlds, (n, 3).
            cam_mat: camera rotation matrices, (n, 3, 3) (columns = camera axes in world).
            ids: world indices, (n,).
            rng: noise generator (needed when noise or dropout is on).

        Returns:
            (n, 1, H, W) float32 normalised depth in [0, 1].
        """
        cfg = self.cfg
        n = ids.size
        if n == 0:
            return np.zeros((0, 1, cfg.height, cfg.width), dtype=np.float32)
        vec = np.einsum("nij,rj->nri", cam_mat, self._dirs_cam)
        pnt = np.broadcast_to(cam_pos[:, None, :], vec.shape)
        dist, _ = batch.ray(pnt, vec, geomgroup=self._groups, flg_static=True, ids=ids.astype(np.int32))
        z = np.where(dist < 0.0, cfg.far, dist * self._axis_cos[None, :])
        depth = (np.clip(z, cfg.near, cfg.far) - cfg.near) / (cfg.far - cfg.near)
        if cfg.noise_std > 0.0 or cfg.dropout > 0.0:
            if rng is None:
                raise ValueError("depth noise needs an rng")
            if cfg.noise_std > 0.0:
                depth = np.clip(depth + rng.normal(0.0, cfg.noise_std, size=depth.shape), 0.0, 1.0)
            if cfg.dropout > 0.0:
                depth = np.where(rng.random(depth.shape) < cfg.dropout, 0.0, depth)
        return depth.reshape(n, 1, cfg.height, cfg.width).astype(np.float32)


def scandot_offsets() -> np.ndarray:
    """Scandot sample points in the base's yaw frame, (132, 2) m.

    12 x 11 grid (Extreme Parkour's layout): x in linspace(-0.45, 1.2, 12) (forward),
    y in linspace(-0.75, 0.75, 11) (left); x-major order.
    """
    xs = np.linspace(-0.45, 1.2, 12)
    ys = np.linspace(-0.75, 0.75, 11)
    xx, yy = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([xx.ravel(), yy.ravel()], axis=-1)


def scandots(
    base_pos: np.ndarray,
    yaw: np.ndarray,
    offsets: np.ndarray,
    height_fn: Callable[[np.ndarray], np.ndarray],
    base_height_target: float,
) -> np.ndarray:
    """Terrain heights around the robot, relative to where the ground would be under a nominal base.

    ``scandots = clip(h(p) - (z_base - h_target), -1, 1)``: 0 on flat ground with the base at its
    target height, positive for terrain rising above that level (a step up reads +step height).

    Args:
        base_pos: (N, 3) base positions.
        yaw: (N,) base yaw.
        offsets: (K, 2) sample points in the yaw frame (:func:`scandot_offsets`).
        height_fn: surface height at world xy points, (M, 2) -> (M,).
        base_height_target: nominal base height above the ground, m.

    Returns:
        (N, K) float32.
    """
    c, s = np.cos(yaw), np.sin(yaw)
    px = base_pos[:, None, 0] + c[:, None] * offsets[None, :, 0] - s[:, None] * offsets[None, :, 1]
    py = base_pos[:, None, 1] + s[:, None] * offsets[None, :, 0] + c[:, None] * offsets[None, :, 1]
    pts = np.stack([px, py], axis=-1).reshape(-1, 2)
    h = height_fn(pts).reshape(base_pos.shape[0], offsets.shape[0])
    ground = base_pos[:, 2:3] - base_height_target
    return np.clip(h - ground, -1.0, 1.0).astype(np.float32)


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternions (w, x, y, z): (N, 4) -> (N, 3, 3)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )


def yaw_from_quat(q: np.ndarray) -> np.ndarray:
    """Heading (rotation about world z) of quaternions (w, x, y, z): (N, 4) -> (N,)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def roll_pitch_from_gravity(gravity_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Torso roll and pitch from the unit gravity vector in the base frame, (N, 3) -> 2 x (N,)."""
    roll = np.arctan2(-gravity_b[:, 1], -gravity_b[:, 2])
    pitch = np.arcsin(np.clip(gravity_b[:, 0], -1.0, 1.0))
    return roll, pitch


def world_to_yaw_frame(vec_xy: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Rotate world xy vectors into the robot's yaw frame: (N, ..., 2), (N,) -> (N, ..., 2)."""
    c, s = np.cos(yaw), np.sin(yaw)
    shape = (-1,) + (1,) * (vec_xy.ndim - 2)
    c, s = c.reshape(shape), s.reshape(shape)
    x, y = vec_xy[..., 0], vec_xy[..., 1]
    return np.stack([c * x + s * y, -s * x + c * y], axis=-1)
