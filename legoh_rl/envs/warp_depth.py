"""The head depth camera cast by MuJoCo Warp on the simulation's device (``env.physics=warp``).

:class:`~legoh_rl.envs.sensors.DepthCamera` renders on the host: a height-map march plus an
exact obstacle caster, about 200 us per world on a CPU core, which caps a student's env at a few
thousand steps/s whatever steps the physics. :class:`WarpDepthCamera` casts the same pixel rays
with ``mujoco_warp.rays`` from the camera poses the simulation already holds on its device
(``Data.cam_xpos``, ``Data.cam_xmat``) against the terrain geoms (groups 0 and 1: the ground
heightfield and the obstacles; the robot's own bodies never occlude the view), normalises and
perturbs them with torch on that device, and leaves the images there: nothing of the depth path
crosses to the host. The rays are MuJoCo's exact ray-geom tests (float32), so the images equal
C MuJoCo's ``mj_ray`` depth (:meth:`DepthCamera.render_exact`) rather than the host march's
approximation of it.

``mujoco_warp.rays`` casts every world's rays at once (it has no world subsets); the env keeps
the rows of the worlds whose perception ticks.
"""

from __future__ import annotations

import torch

from legoh_rl.envs.robots import TERRAIN_GEOM_GROUPS
from legoh_rl.envs.sensors import DepthCamera, DepthCameraConfig

__all__ = ["WarpDepthCamera"]


class WarpDepthCamera:
    """Depth images of all ``N`` worlds of a :class:`~legoh_rl.envs.warp_physics.WarpWorlds`,
    computed on its device.

    Args:
        worlds: the Warp-stepped worlds (their ``m``, ``d``, ``wp``, ``mjw`` and
            ``torch_device``).
        camera_id: the model camera to render (the robot's head camera).
        cfg: image size, clipping and noise (the march settings are not used: rays are exact).
        fovy_deg: vertical field of view, degrees (pixel rays as :class:`DepthCamera`'s).
        seed: seeds the noise and dropout generator (on the device).

    Attributes:
        generator: the torch generator of noise and dropout (its state belongs in checkpoints).
    """

    def __init__(self, worlds, camera_id: int, cfg: DepthCameraConfig, fovy_deg: float, seed: int = 0) -> None:
        self.worlds, self.camera_id, self.cfg = worlds, int(camera_id), cfg
        wp, dev = worlds.wp, worlds.torch_device
        rays = DepthCamera(cfg, fovy_deg, obstacle_caster=None)  # its pixel rays, the same for both cameras
        self._dirs_cam = torch.as_tensor(rays._dirs_cam, dtype=torch.float32, device=dev)  # (R, 3) unit, camera frame
        self._axis_cos = torch.as_tensor(rays._axis_cos, dtype=torch.float32, device=dev)  # (R,)
        N, R = worlds.num_worlds, self._dirs_cam.shape[0]
        self._pnt = torch.zeros((N, R, 3), dtype=torch.float32, device=dev)  # ray origins and directions,
        self._vec = torch.zeros((N, R, 3), dtype=torch.float32, device=dev)  # shared with Warp (zero-copy)
        self._dist = torch.zeros((N, R), dtype=torch.float32, device=dev)
        with wp.ScopedDevice(worlds.device):
            self._wp_pnt = wp.from_torch(self._pnt, dtype=wp.vec3)
            self._wp_vec = wp.from_torch(self._vec, dtype=wp.vec3)
            self._wp_dist = wp.from_torch(self._dist)
            self._geomid = wp.zeros((N, R), dtype=wp.int32)
            self._normal = wp.zeros((N, R), dtype=wp.vec3)
            self._bodyexclude = wp.full(R, -1, dtype=wp.int32)
        # geom groups the rays see (1) or skip (0): MuJoCo's six groups, the terrain's on
        self._geomgroup = wp.types.vector(6, wp.float32)(*[float(g in TERRAIN_GEOM_GROUPS) for g in range(6)])
        self.generator = torch.Generator(device=dev).manual_seed(int(seed))
        worlds.precompile([self._cast])  # the ray kernels, compiled beside nothing else: no first-frame stall

    def _cast(self) -> None:
        """``mujoco_warp.rays`` from ``_pnt`` along ``_vec`` into ``_dist`` (-1: no hit)."""
        w = self.worlds
        w.mjw.rays(w.m, w.d, self._wp_pnt, self._wp_vec, self._geomgroup, True, self._bodyexclude,
                   self._wp_dist, self._geomid, self._normal)

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """``(N, 1, H, W)``: the images :meth:`render` returns."""
        return (self.worlds.num_worlds, 1, self.cfg.height, self.cfg.width)

    def render(self) -> torch.Tensor:
        """Depth images of every world at the simulation's current camera poses.

        Returns:
            (N, 1, H, W) float32 normalised z-depth in [0, 1] on the worlds' device (1.0: nothing
            within ``far``; noise and dropout as the config asks).
        """
        w, cfg = self.worlds, self.cfg
        view = w.wp.to_torch
        with w.wp.ScopedDevice(w.device):
            cam_pos = view(w.d.cam_xpos)[:, self.camera_id]  # (N, 3)
            cam_mat = view(w.d.cam_xmat)[:, self.camera_id].reshape(-1, 3, 3)  # columns: camera axes in world
            self._pnt.copy_(cam_pos[:, None, :].expand_as(self._pnt))
            torch.matmul(self._dirs_cam, cam_mat.transpose(1, 2), out=self._vec)  # (N, R, 3)
            self._cast()
        dist = self._dist
        z = torch.where(dist >= 0.0, dist * self._axis_cos, torch.full_like(dist, cfg.far))  # -1: no hit
        depth = (z.clamp(cfg.near, cfg.far) - cfg.near) / (cfg.far - cfg.near)
        if cfg.noise_std > 0.0:
            noise = torch.randn(depth.shape, generator=self.generator, device=depth.device)
            depth = (depth + cfg.noise_std * noise).clamp(0.0, 1.0)
        if cfg.dropout > 0.0:
            holes = torch.rand(depth.shape, generator=self.generator, device=depth.device) < cfg.dropout
            depth = depth.masked_fill(holes, 0.0)
        return depth.reshape(self.shape)

