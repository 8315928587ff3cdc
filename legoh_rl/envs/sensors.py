"""Batched sensors: head depth camera (ray casting), scandots, contacts, base state.

All functions take ``(N, ...)`` arrays and loop over no world in Python.

Why one file of ~500 lines: the depth camera (its config and its ground-march, fused and exact
obstacle paths) is most of it, and it shares the frame helpers (quaternions, yaw frame) with the
scandots; the ray casters themselves live in ``height_map.py``, ``obstacle_rays.py`` and ``native/``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np
import torch
from array_api_compat import device as array_device

from legoh_rl.envs.array_api import namespace_of
from legoh_rl.envs.height_map import HeightMap, as_grid_sampler, torch_height_fn, yaw_frame_points
from legoh_rl.envs.native import (
    camera_native,
    load_library,
    march_ground_native,
    same_grid,
    unavailable_reason,
)
from legoh_rl.envs.obstacle_rays import ObstacleRayCaster
from legoh_rl.envs.robots import OBSTACLE_GEOM_GROUP, TERRAIN_GEOM_GROUPS
from legoh_rl.kinds import Choice, Integer, Number, check_fields, setting

__all__ = [
    "DepthCameraConfig",
    "DepthCamera",
    "march_ground",
    "resolve_march_backend",
    "torch_height_fn",
    "scandot_offsets",
    "scandots",
    "FOOT_SCAN_OFFSETS",
    "FOOT_SCAN_FAR_OFFSETS",
    "foot_scan_blocks",
    "foot_scan",
    "quat_to_rotmat",
    "yaw_from_quat",
    "roll_pitch_from_gravity",
    "world_to_yaw_frame",
]


MARCH_BACKENDS = ("auto", "native", "torch")
DEPTH_SOURCES = ("auto", "host", "warp")
#: a surface hit this far (m) above the bare ground lies on an obstacle (resolved exactly)
OBSTACLE_MARGIN = 0.02


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
        march_samples: coarse samples per ray of the height-map ray march (see
            :func:`march_ground`): fewer is faster, more resolves thinner features.
        march_refine: regula-falsi steps that locate the hit inside the bracketing samples.
        backend: ray-march implementation: ``"native"`` (the C kernel of
            :mod:`legoh_rl.envs.native`, built with the system C compiler on first use; each ray
            stops at its first sample below the ground), ``"torch"`` (the vectorised reference,
            :func:`march_ground`), or ``"auto"`` (native when it builds, else torch with a warning).
            Both give the same depth to float32 rounding.
        source: who casts the rays: ``"host"`` (this module's :class:`DepthCamera`: the
            height-map march and the obstacle caster, on the CPU), ``"warp"`` (MuJoCo Warp's
            exact rays on the simulation's device, :mod:`legoh_rl.envs.warp_depth`; needs
            ``env.physics=warp``), or ``"auto"`` (``host`` on either backend: on an H100 the
            host march on 16 threads gave the student ~10x the env steps/s of Warp's rays).
    """

    height: int = setting(64, Integer(1))
    width: int = setting(64, Integer(1))
    near: float = setting(0.2, Number(0))
    far: float = setting(4.0, Number(0, low_open=True))
    noise_std: float = setting(0.0, Number(0))
    dropout: float = setting(0.0, Number(0, 1))
    march_samples: int = setting(12, Integer(2))
    march_refine: int = setting(3, Integer(0))
    backend: str = setting("auto", Choice(MARCH_BACKENDS, what="depth backend"))
    source: str = setting("auto", Choice(DEPTH_SOURCES, what="depth source"))

    def __post_init__(self) -> None:
        check_fields(self)  # each field against its kind (legoh_rl/kinds.py)
        if not 0.0 <= self.near < self.far:
            raise ValueError(f"need 0 <= near < far, got near={self.near}, far={self.far}")


def resolve_march_backend(name: str) -> str:
    """The ray-march implementation a :class:`DepthCameraConfig` ``backend`` gives on this machine:
    ``"native"`` or ``"torch"``.

    Raises:
        ValueError: ``name`` is not one of ``MARCH_BACKENDS``.
        RuntimeError: ``"native"`` was asked for and the kernel cannot be built (says why).
    """
    if name not in MARCH_BACKENDS:
        raise ValueError(f"depth backend must be one of {MARCH_BACKENDS}, got {name!r}")
    if name == "torch":
        return "torch"
    if load_library() is not None:
        return "native"
    if name == "native":
        raise RuntimeError(f"depth backend 'native' asked for, but its kernel cannot be built: {unavailable_reason()}")
    warnings.warn(f"native depth kernel unavailable ({unavailable_reason()}); using the torch ray march",
                  RuntimeWarning, stacklevel=2)
    return "torch"


class DepthCamera:
    """Renders the head depth camera of many worlds at once.

    Rays see only the terrain: the ground (group 0) and obstacles (group 1), so the robot's own
    body (groups 2 and 3) never occludes the view.

    Args:
        cfg: the camera configuration.
        fovy_deg: vertical field of view (the model camera's ``fovy``); the image is square in
            angle when height == width.
        obstacle_caster: exact ray caster of the obstacle geoms (group 1, static, identical in
            every world), e.g. ``ObstacleRayCaster.from_model(model)``; without one the obstacle
            rays go through ``Batch.ray`` (several times slower: it tests every obstacle). Also
            settable afterwards as the attribute ``obstacle_caster`` (``None`` restores
            ``Batch.ray``).
    """

    def __init__(self, cfg: DepthCameraConfig, fovy_deg: float,
                 obstacle_caster: ObstacleRayCaster | None = None) -> None:
        self.cfg = cfg
        self.obstacle_caster = obstacle_caster
        #: the ray march in use, "native" or "torch" (see :func:`resolve_march_backend`)
        self.backend = resolve_march_backend(cfg.backend)
        tan_y = math.tan(math.radians(fovy_deg) / 2.0)
        tan_x = tan_y * cfg.width / cfg.height
        # pixel centres; row 0 is the top of the image, column 0 the left
        v = (1.0 - (np.arange(cfg.height) + 0.5) / cfg.height * 2.0) * tan_y
        u = ((np.arange(cfg.width) + 0.5) / cfg.width * 2.0 - 1.0) * tan_x
        uu, vv = np.meshgrid(u, v)
        dirs = np.stack([uu, vv, -np.ones_like(uu)], axis=-1).reshape(-1, 3)  # camera frame
        self._axis_cos = 1.0 / np.linalg.norm(dirs, axis=1)  # cos(angle to the optical axis)
        self._dirs_cam = dirs * self._axis_cos[:, None]  # unit rays
        # MuJoCo rays see only obstacles (group 1); the ground (group 0) is ray-marched.
        self._obstacle_groups = np.zeros(mujoco.mjNGROUP, dtype=np.uint8)
        self._obstacle_groups[OBSTACLE_GEOM_GROUP] = 1

    def render(
        self,
        batch,
        cam_pos: np.ndarray,
        cam_mat: np.ndarray,
        ids: np.ndarray,
        surface_fn: Callable[[np.ndarray], np.ndarray],
        ground_fn: Callable[[np.ndarray], np.ndarray],
        rng: np.random.Generator | None = None,
        z_max: np.ndarray | None = None,
        z_min: np.ndarray | None = None,
    ) -> np.ndarray:
        """Depth images of worlds ``ids``.

        Every ray is first marched (:func:`march_ground`) against the surface height map, where
        obstacles appear as their rasterised tops. Rays whose hit lies on an obstacle cell are
        then resolved exactly: the obstacle caster (or ``Batch.ray`` without one) against the
        obstacle geoms (group 1), and a march against the bare ground (group 0) for rays that pass
        beside them. MuJoCo's own ray-heightfield test scans every cell in the bounding rectangle
        of the ray's path, hundreds of cells per ray on a trail grid, which made depth 40x slower
        than physics.

        Args:
            batch: the ``mujoco.batch.Batch`` of the worlds.
            cam_pos: camera positions of those worlds, (n, 3).
            cam_mat: camera rotation matrices, (n, 3, 3) (columns = camera axes in world).
            ids: world indices, (n,).
            surface_fn: surface height (ground and obstacle tops), (M, 2) -> (M,).
            ground_fn: bare ground height at world xy points, (M, 2) -> (M,).
            rng: noise generator (needed when noise or dropout is on).
            z_max: (n,) highest terrain around each camera (optional): rays are marched only
                from where they descend below it.
            z_min: (n,) lowest terrain around each camera (optional): rays are marched only
                until they descend below it.

        Returns:
            (n, 1, H, W) float32 normalised depth in [0, 1].
        """
        cfg = self.cfg
        n = ids.size
        if n == 0:
            return np.zeros((0, 1, cfg.height, cfg.width), dtype=np.float32)
        t_ray = cfg.far / self._axis_cos  # (R,) the distance along each pixel ray where z-depth reaches far
        vec = None  # (n, R, 3) world-frame rays, only where a path needs them all
        if self._fused(surface_fn, ground_fn):
            # 1+2 in one native call: rotate the pixel rays, march the surface map, flag obstacle hits
            # (and, with an obstacle caster, resolve the flagged rays against the geoms in the same call)
            dist, on_obstacle = camera_native(surface_fn, ground_fn, cam_pos, cam_mat, self._dirs_cam, t_ray,
                                              samples=cfg.march_samples, refine=cfg.march_refine, z_max=z_max,
                                              z_min=z_min, obstacle_margin=OBSTACLE_MARGIN,
                                              threads=torch.get_num_threads(), caster=self.obstacle_caster)
            if self.obstacle_caster is not None:
                on_obstacle = None  # resolved
        else:
            vec = np.matmul(self._dirs_cam, cam_mat.transpose(0, 2, 1))
            # 1) march every ray against the surface map (ground + rasterised obstacle tops)
            dist = self._march(cam_pos, vec, np.broadcast_to(t_ray, vec.shape[:2]), surface_fn, z_max=z_max,
                               z_min=z_min)
            # 2) rays whose hit lies on an obstacle: exact obstacle ray + bare-ground march. The
            # march stopped on the surface, so the ray's height there is the surface height.
            hit = np.isfinite(dist)
            hit_xyz = cam_pos[:, None, :] + np.where(hit, dist, 0.0)[..., None] * vec
            ground = self._heights(ground_fn, hit_xyz[..., :2].reshape(-1, 2))
            on_obstacle = hit & (hit_xyz[..., 2] - ground.reshape(dist.shape) > OBSTACLE_MARGIN)
        if on_obstacle is not None and on_obstacle.any():
            dist = self._exact_on_obstacles(batch, cam_pos, cam_mat, vec, t_ray, ids, on_obstacle, dist, ground_fn,
                                            z_max, z_min)
        depth = self._normalised(dist)
        if cfg.noise_std > 0.0 or cfg.dropout > 0.0:
            if rng is None:
                raise ValueError("depth noise needs an rng")
            if cfg.noise_std > 0.0:
                depth = np.clip(depth + rng.normal(0.0, cfg.noise_std, size=depth.shape), 0.0, 1.0)
            if cfg.dropout > 0.0:
                depth = np.where(rng.random(depth.shape) < cfg.dropout, 0.0, depth)
        return depth.reshape(n, 1, cfg.height, cfg.width).astype(np.float32)

    def render_exact(self, batch, cam_pos: np.ndarray, cam_mat: np.ndarray, ids: np.ndarray) -> np.ndarray:
        """Reference depth images by MuJoCo's exact ray casting against every terrain geom.

        ``Batch.ray`` on the ground heightfield and the obstacles (groups 0 and 1), no noise: the
        slow path :meth:`render` approximates (tens of times slower on a trail grid; for tests
        and benchmarks). Arguments as :meth:`render`; returns (n, 1, H, W) float32 in [0, 1].
        """
        groups = np.zeros(mujoco.mjNGROUP, dtype=np.uint8)
        groups[list(TERRAIN_GEOM_GROUPS)] = 1
        vec = np.matmul(self._dirs_cam, cam_mat.transpose(0, 2, 1))
        dist, _ = batch.ray(np.broadcast_to(cam_pos[:, None], vec.shape), vec, geomgroup=groups,
                            ids=np.asarray(ids, dtype=np.int32))
        depth = self._normalised(np.where(dist < 0.0, np.inf, dist))
        return depth.reshape(-1, 1, self.cfg.height, self.cfg.width).astype(np.float32)

    def _fused(self, surface_fn, ground_fn) -> bool:
        """Whether :meth:`render` can take the one-call native path (:func:`camera_native`)."""
        return (self.backend == "native" and isinstance(surface_fn, HeightMap) and isinstance(ground_fn, HeightMap)
                and same_grid(surface_fn, ground_fn))

    def _march(self, origin, dirs, t_max, height_fn, z_max=None, z_min=None, t_min=None) -> np.ndarray:
        """:func:`march_ground` with this camera's samples, on its backend (the native kernel needs
        a :class:`HeightMap`; other height functions take the torch march). Native runs on as many
        threads as torch has (the env renders inside ``torch_threads``)."""
        cfg = self.cfg
        if self.backend == "native" and isinstance(height_fn, HeightMap):
            return march_ground_native(height_fn, origin, dirs, t_max, samples=cfg.march_samples,
                                       refine=cfg.march_refine, z_max=z_max, z_min=z_min, t_min=t_min,
                                       threads=torch.get_num_threads())
        return march_ground(origin, dirs, t_max, height_fn, samples=cfg.march_samples, refine=cfg.march_refine,
                            z_max=z_max, z_min=z_min, t_min=t_min)

    def _heights(self, height_fn, xy: np.ndarray) -> np.ndarray:
        """Heights at world points (M, 2) -> (M,) numpy, native where the backend allows."""
        if self.backend == "native" and isinstance(height_fn, HeightMap):
            return height_fn.numpy(xy)
        return torch_height_fn(height_fn)(torch.as_tensor(xy, dtype=torch.float32)).numpy()

    def _normalised(self, dist: np.ndarray) -> np.ndarray:
        """Distances along the rays (n, R), ``inf`` for no hit -> normalised z-depth (n, R)."""
        cfg = self.cfg
        z = np.where(np.isfinite(dist), dist * self._axis_cos[None, :], cfg.far)
        return (np.clip(z, cfg.near, cfg.far) - cfg.near) / (cfg.far - cfg.near)

    def _exact_on_obstacles(self, batch, cam_pos, cam_mat, vec, t_ray, ids, flagged, dist, ground_fn, z_max=None,
                            z_min=None) -> np.ndarray:
        """Exact distances for the ``flagged`` (n, R) rays.

        The obstacle rays: with an obstacle caster, one call over all flagged rays. Without one,
        ``Batch.ray``: worlds are grouped by their number of flagged rays into power-of-two
        buckets; each bucket is one padded call (at most ~13 calls, never one per world), so a
        world that faces a forest does not make every other world cast thousands of rays. The
        bare-ground march: one call over all flagged rays, each starting where it met the surface
        (the bare ground lies at or below the surface). ``vec`` (n, R, 3) are the world-frame
        rays, or None: then the flagged ones are rotated here from ``cam_mat`` (n, 3, 3).
        """
        out = dist  # a fresh array of render's, updated in place
        w, r = np.nonzero(flagged)
        vec_f = vec[w, r] if vec is not None else np.matmul(cam_mat[w], self._dirs_cam[r][:, :, None])[..., 0]
        t_max = t_ray[r]
        if self.obstacle_caster is not None:
            obstacle = self.obstacle_caster.cast(cam_pos[w], vec_f, t_max, threads=torch.get_num_threads())
        else:
            if vec is None:
                vec = np.matmul(self._dirs_cam, cam_mat.transpose(0, 2, 1))
            obstacle = self._batch_ray_obstacles(batch, cam_pos, vec, ids, flagged)[w, r]
        ground = self._march(cam_pos[w], vec_f[:, None, :], t_max[:, None], ground_fn,
                             z_max=None if z_max is None else z_max[w],
                             z_min=None if z_min is None else z_min[w], t_min=dist[w, r][:, None])
        out[w, r] = np.minimum(obstacle, ground[:, 0])
        return out

    def _batch_ray_obstacles(self, batch, cam_pos, vec, ids, flagged) -> np.ndarray:
        """``Batch.ray`` distances to the obstacles of the ``flagged`` (n, R) rays, bucketed by
        world (see :meth:`_exact_on_obstacles`); (n, R) with ``inf`` for misses and unflagged."""
        counts = flagged.sum(axis=1)
        worlds = np.flatnonzero(counts)
        obstacle = np.full(flagged.shape, np.inf)
        buckets = np.ceil(np.log2(counts[worlds])).astype(np.int64)
        for b in np.unique(buckets):
            sel = worlds[buckets == b]
            k = int(counts[sel].max())
            order = np.argsort(~flagged[sel], axis=1, kind="stable")[:, :k]  # flagged rays first
            valid = np.arange(k)[None, :] < counts[sel, None]
            sub_vec = np.take_along_axis(vec[sel], order[..., None], axis=1)
            obs, _ = batch.ray(np.broadcast_to(cam_pos[sel, None, :], sub_vec.shape), sub_vec,
                               geomgroup=self._obstacle_groups, flg_static=True, ids=ids[sel].astype(np.int32))
            rows = np.repeat(sel, k).reshape(sel.size, k)
            obstacle[rows[valid], order[valid]] = np.where(obs < 0.0, np.inf, obs)[valid]
        return obstacle


def march_ground(
    origin: np.ndarray,
    dirs: np.ndarray,
    t_max: np.ndarray,
    ground_fn: Callable,
    samples: int = 16,
    refine: int = 3,
    z_max: np.ndarray | None = None,
    z_min: np.ndarray | None = None,
    t_min: np.ndarray | None = None,
) -> np.ndarray:
    """First intersection of rays with a height map, vectorised over every ray (torch, float32).

    Each ray ``o + t d`` is sampled at ``samples`` points in (t_0, t_1]; the first sample below
    the ground brackets the hit, which ``refine`` regula-falsi steps then locate (exact where the
    ground is planar between the bracket's ends). ``t_0`` is where the ray descends below
    ``z_max``, the highest terrain it can meet (0 without ``z_max``), and ``t_1`` where it
    descends below ``z_min``, the lowest (``t_max`` without ``z_min``): past ``t_1`` the ray is
    under every surface it could have met, so the hit lies in between. The narrower the bracket,
    the denser the samples where hits are.

    Args:
        origin: ray origins per world, (n, 3).
        dirs: unit ray directions, (n, R, 3).
        t_max: longest distance to look along each ray, (n, R).
        ground_fn: height at xy points, (M, 2) -> (M,): a :class:`~legoh_rl.envs.height_map.HeightMap`
            (fastest: the march then runs in the map's grid coordinates), a torch function (see
            :func:`torch_height_fn`) or a numpy one.
        samples: coarse samples per ray.
        refine: regula-falsi iterations inside the bracket.
        z_max: (n,) upper bound of the terrain height each world's rays can meet, or None.
        z_min: (n,) lower bound of that terrain height, or None.
        t_min: (n, R) distances before which no ray can hit (the march starts there), or None.

    Returns:
        (n, R) float64 distance to the hit along each ray; ``inf`` where the ray stays above.
    """
    hm = as_grid_sampler(ground_fn)
    o = torch.as_tensor(origin, dtype=torch.float32)
    d = torch.tensor(np.asarray(dirs, dtype=np.float32))
    tm = torch.tensor(np.asarray(t_max, dtype=np.float32))  # a copy: t_max may be a read-only view
    oz, dz = o[:, 2, None], d[..., 2]  # (n, 1), (n, R)
    og, dg = hm.to_grid(o[:, :2])[:, None, :], hm.dirs_to_grid(d[..., :2])  # (n, 1, 2), (n, R, 2)
    down = dz < 0.0
    inv_down = 1.0 / (-dz).clamp_min(1e-6)
    t0 = torch.zeros_like(tm)
    if z_max is not None:
        above = oz - torch.as_tensor(np.asarray(z_max, dtype=np.float32))[:, None]  # (n, 1)
        t0 = torch.where(down, (above * inv_down).clamp_min(0.0), t0)
        t0 = torch.where(~down & (above > 0.0), tm, t0)  # level/upward rays above all terrain: no hit
        t0 = torch.minimum(t0, tm)
    if t_min is not None:
        t0 = torch.minimum(torch.maximum(t0, torch.as_tensor(np.asarray(t_min, dtype=np.float32))), tm)
    if z_min is not None:  # below z_min the ray is under all terrain: the hit came before
        depth = oz - torch.as_tensor(np.asarray(z_min, dtype=np.float32))[:, None] + 1e-3
        tm = torch.where(down, torch.minimum(tm, depth.clamp_min(0.0) * inv_down), tm)
        tm = torch.maximum(tm, t0)
    frac = torch.arange(1, samples + 1, dtype=torch.float32) / samples
    t = torch.addcmul(t0[..., None], (tm - t0)[..., None], frac)  # (n, R, S)
    g = _ray_points(og, t, dg)  # (n, R, S, 2)
    f = torch.addcmul(oz[..., None], t, dz[..., None]) - hm.sample_grid(g)
    hit, k = (f <= 0.0).max(dim=-1, keepdim=True)  # any sample below the ground; the first one
    hit = hit[..., 0]
    t_hi, f_hi = t.gather(-1, k)[..., 0], f.gather(-1, k)[..., 0]
    prev = (k - 1).clamp_min(0)
    first = k[..., 0] == 0
    # at t0 the ray is at (or above) z_max >= terrain, or at the camera: a valid bracket start
    z0 = oz + t0 * dz - hm.sample_grid(torch.addcmul(og, t0[..., None], dg))
    t_lo = torch.where(first, t0, t.gather(-1, prev)[..., 0])
    f_lo = torch.where(first, z0, f.gather(-1, prev)[..., 0])
    for _ in range(refine):
        t_mid = t_lo + (t_hi - t_lo) * (f_lo / (f_lo - f_hi).clamp_min(1e-9)).clamp(0.0, 1.0)
        f_mid = oz + t_mid * dz - hm.sample_grid(torch.addcmul(og, t_mid[..., None], dg))
        above = f_mid > 0.0
        t_lo, f_lo = torch.where(above, t_mid, t_lo), torch.where(above, f_mid, f_lo)
        t_hi, f_hi = torch.where(above, t_hi, t_mid), torch.where(above, f_hi, f_mid)
    t_hit = t_lo + (t_hi - t_lo) * (f_lo / (f_lo - f_hi).clamp_min(1e-9)).clamp(0.0, 1.0)
    return torch.where(hit, t_hit, torch.full_like(t_hit, float("inf"))).double().numpy()


def _ray_points(og: torch.Tensor, t: torch.Tensor, dg: torch.Tensor) -> torch.Tensor:
    """``og + t * dg`` for (n, 1, 2) origins, (n, R, S) distances and (n, R, 2) directions ->
    (n, R, S, 2), written one coordinate at a time (2.5x faster than one broadcast addcmul)."""
    g = torch.empty(*t.shape, 2)
    for c in range(2):
        torch.mul(t, dg[..., c : c + 1], out=g[..., c]).add_(og[..., c : c + 1])
    return g


def _xy_grid(xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """The points of the grid ``xs`` (forward) x ``ys`` (left), x-major: (len(xs) * len(ys), 2)."""
    xx, yy = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([xx.ravel(), yy.ravel()], axis=-1)


def scandot_offsets() -> np.ndarray:
    """Scandot sample points in the base's yaw frame, (132, 2) m.

    12 x 11 grid (Extreme Parkour's layout): x in linspace(-0.45, 1.2, 12) (forward),
    y in linspace(-0.75, 0.75, 11) (left); x-major order.
    """
    return _xy_grid(np.linspace(-0.45, 1.2, 12), np.linspace(-0.75, 0.75, 11))


#: Foot-scan sample points in a foot's yaw frame, (45, 2) m (``HikingEnvConfig.foot_scan``): a
#: 9 x 5 grid at 0.05 m, x in [-0.10, 0.30] forward of the foot body's origin (the ankle; H1's
#: sole spans about [-0.07, 0.17], G1's [-0.07, 0.14]), y in [-0.10, 0.10] (left); x-major. It
#: covers the sole and ~0.13 m ahead of the toe, where a foot landing short of a stone sees the
#: stone's edge; the scandots' 0.15 m spacing is coarser than that miss.
FOOT_SCAN_OFFSETS = _xy_grid(np.linspace(-0.10, 0.30, 9), np.linspace(-0.10, 0.10, 5))

#: The far foot scan's sample points in a foot's yaw frame, (35, 2) m (``HikingEnvConfig.foot_scan_far``):
#: a 7 x 5 grid at 0.05 m, x in [0.35, 0.65] forward of the ankle (past :data:`FOOT_SCAN_OFFSETS`'
#: reach, same lateral columns), x-major. From a foot standing at a pit's near rim it reaches the
#: far rim of Gap's level-3 pits (0.44 m wide, the ankle ~0.17 m behind the toe), which the near
#: grid does not: the oracle then reads a pit's width where it takes off, not only under the
#: swinging foot.
FOOT_SCAN_FAR_OFFSETS = _xy_grid(np.linspace(0.35, 0.65, 7), np.linspace(-0.10, 0.10, 5))


def foot_scan_blocks(far: bool = False) -> tuple[np.ndarray, ...]:
    """The foot scan's blocks of sample points, in the order their heights follow the scandots.

    Each block is scanned under both feet (:func:`foot_scan`: the left foot's heights, then the
    right's) before the next block, so ``far`` appends columns after the near scan's ``2 x 45``
    and a policy trained without it widens onto it (``checkpoint.init_widen``).

    Args:
        far: add :data:`FOOT_SCAN_FAR_OFFSETS` after :data:`FOOT_SCAN_OFFSETS`.

    Returns:
        ``(FOOT_SCAN_OFFSETS,)`` or ``(FOOT_SCAN_OFFSETS, FOOT_SCAN_FAR_OFFSETS)``, each (K_b, 2).
    """
    return (FOOT_SCAN_OFFSETS, FOOT_SCAN_FAR_OFFSETS) if far else (FOOT_SCAN_OFFSETS,)


def scandots(
    base_pos: np.ndarray,
    yaw: np.ndarray,
    offsets: np.ndarray,
    height_fn: Callable[[np.ndarray], np.ndarray],
    base_height_target: float,
    heights_around: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None = None,
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
        heights_around: optional faster lookup of the same heights, ``(xy (N, 2), yaw (N,),
            offsets (K, 2)) -> (N, K)`` (e.g. ``GridTrails.height_around``); used instead of
            rotating the points here and calling ``height_fn``.

    Returns:
        (N, K) float32.
    """
    n, k = base_pos.shape[0], offsets.shape[0]
    if heights_around is not None:
        h = heights_around(base_pos[:, :2], yaw, offsets)
    else:
        h = height_fn(yaw_frame_points(base_pos[:, :2], yaw, offsets).reshape(-1, 2)).reshape(n, k)
    ground = base_pos[:, 2:3] - base_height_target
    return np.clip(h - ground, -1.0, 1.0).astype(np.float32)


def foot_scan(feet_pos, feet_quat, offsets, height_fn: Callable, foot_rest_height: float):
    """Terrain heights around each foot, relative to its sole (numpy arrays or torch tensors).

    ``foot_scan = clip(h(p) - (z_foot - foot_rest_height), -1, 1)`` at the points ``p`` of
    ``offsets`` in each foot's yaw frame (the heading of the foot body): 0 on flat ground under a
    standing foot, -d where the points lie over a pit of depth d, +s over a step of height s.

    Args:
        feet_pos: (n, 2, 3) world positions of the (left, right) foot bodies.
        feet_quat: (n, 2, 4) their orientations (w, x, y, z).
        offsets: (K, 2) sample points in a foot's yaw frame (:data:`FOOT_SCAN_OFFSETS`), of the
            same kind as ``feet_pos``.
        height_fn: surface height at world xy points, (M, 2) -> (M,), of the same kind.
        foot_rest_height: height of a foot body's origin above the ground it stands on, m
            (:class:`~legoh_rl.envs.robots.RobotSpec`).

    Returns:
        (n, 2K): the left foot's K heights, then the right's, in ``offsets``' order.
    """
    xp = namespace_of(feet_pos)
    n, k = feet_pos.shape[0], offsets.shape[0]
    yaw = xp.reshape(yaw_from_quat(feet_quat), (-1,))  # (2n,)
    points = yaw_frame_points(xp.reshape(feet_pos[..., :2], (-1, 2)), yaw, offsets)  # (2n, K, 2)
    h = xp.reshape(height_fn(xp.reshape(points, (-1, 2))), (n, 2, k))
    sole = feet_pos[..., 2] - foot_rest_height  # (n, 2) the ground a standing foot would be on
    return xp.reshape(xp.clip(h - sole[..., None], -1.0, 1.0), (n, 2 * k))


def _quat_product_map() -> np.ndarray:
    """(16, 9) coefficients: vec(R) = vec(q q^T) @ map + vec(I) for a unit quaternion q = (w, x, y, z)."""
    w, x, y, z = range(4)
    terms = {  # R entry (row-major) -> [(coefficient, i, j)] over products q_i q_j, identity added apart
        0: [(-2, y, y), (-2, z, z)], 1: [(2, x, y), (-2, w, z)], 2: [(2, x, z), (2, w, y)],
        3: [(2, x, y), (2, w, z)], 4: [(-2, x, x), (-2, z, z)], 5: [(2, y, z), (-2, w, x)],
        6: [(2, x, z), (-2, w, y)], 7: [(2, y, z), (2, w, x)], 8: [(-2, x, x), (-2, y, y)],
    }
    m = np.zeros((16, 9))
    for entry, products in terms.items():
        for coef, i, j in products:
            m[4 * i + j, entry] += coef
    return m


_QUAT_PRODUCTS_TO_R = _quat_product_map()
_EYE9 = np.eye(3).reshape(9)


def quat_to_rotmat(q):
    """Rotation matrices of unit quaternions (w, x, y, z): (N, 4) -> (N, 3, 3) (numpy, float64; or a
    torch tensor of the same dtype and device).

    ``R = I + 2 [[-(y^2+z^2), xy - wz, xz + wy], [xy + wz, -(x^2+z^2), yz - wx], [xz - wy, yz + wx,
    -(x^2+y^2)]]``, evaluated as one product of the quaternions' outer products with a constant
    (16, 9) map (a handful of array operations for any N).
    """
    if not isinstance(q, torch.Tensor):
        q = np.asarray(q, dtype=np.float64)
    xp = namespace_of(q)
    outer = xp.reshape(q[:, :, None] * q[:, None, :], (-1, 16))
    products, eye = (xp.asarray(c, dtype=q.dtype, device=array_device(q)) for c in (_QUAT_PRODUCTS_TO_R, _EYE9))
    return xp.reshape(outer @ products + eye, (-1, 3, 3))


def yaw_from_quat(q):
    """Heading (rotation about world z) of quaternions (w, x, y, z): (..., 4) -> (...) (numpy
    arrays or torch tensors)."""
    xp = namespace_of(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return xp.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def roll_pitch_from_gravity(gravity_b):
    """Torso roll and pitch from the unit gravity vector in the base frame, (N, 3) -> 2 x (N,)
    (numpy arrays or torch tensors)."""
    xp = namespace_of(gravity_b)
    roll = xp.atan2(-gravity_b[:, 1], -gravity_b[:, 2])
    pitch = xp.asin(xp.clip(gravity_b[:, 0], -1.0, 1.0))
    return roll, pitch


def world_to_yaw_frame(vec_xy, yaw):
    """Rotate world xy vectors into the robot's yaw frame: (N, ..., 2), (N,) -> (N, ..., 2) (numpy
    arrays or torch tensors)."""
    xp = namespace_of(vec_xy)
    c, s = xp.cos(yaw), xp.sin(yaw)
    shape = (-1,) + (1,) * (vec_xy.ndim - 2)
    c, s = xp.reshape(c, shape), xp.reshape(s, shape)
    x, y = vec_xy[..., 0], vec_xy[..., 1]
    return xp.stack([c * x + s * y, -s * x + c * y], axis=-1)
