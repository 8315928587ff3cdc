"""The worlds' body state: where observations and rewards start.

:class:`BodyStateReader` turns the simulation's live arrays (qpos, qvel, contact sensors, body
positions, actuator forces) and the terrain under the robot into named ``(n, ...)`` arrays for
any subset of worlds, wherever those arrays live: the host's float64 numpy arrays (the host
step) or a device's float32 torch tensors (the device-resident step, docs/gpu_physics.md). It
has two paths that give the same values:

* Python (:meth:`BodyStateReader.read_python`), written once against the array API
  (:mod:`legoh_rl.envs.array_api`): the reference, readable line by line, the device-resident
  step's body state, and the host's fallback when the native library is unavailable
  (``LEGOH_RL_NATIVE=0``, no compiler) or the trail source offers no grids to read directly;
* native (``lh_body_state`` in ``native/body_state.c``): the host's fast path, one C call for
  everything, ~40 numpy calls fewer per control step (``tests/test_body_state.py`` holds the two
  to each other, and the Python path on torch tensors to the same values).
"""

from __future__ import annotations

import ctypes
from collections.abc import Mapping

import numpy as np

from legoh_rl.envs.array_api import namespace_of
from legoh_rl.envs.device_terrain import HostTerrain
from legoh_rl.envs.height_map import HeightMap
from legoh_rl.envs.native.build import load_library
from legoh_rl.envs.robots import BuiltModel
from legoh_rl.envs.sensors import quat_to_rotmat, roll_pitch_from_gravity

__all__ = ["BodyStateReader", "CONTACT_FORCE_THRESHOLD", "FLOAT_FIELDS", "FLAG_FIELDS", "LIVE_ARRAYS"]

CONTACT_FORCE_THRESHOLD = 1.0  # N: a foot is in contact above this net force

#: The float64 outputs in the native kernel's order, with their per-world shapes (A = leg joints,
#: P = penalised bodies).
FLOAT_FIELDS = (
    ("pos", (3,)), ("rot", (3, 3)), ("gravity_b", (3,)), ("roll", ()), ("pitch", ()), ("yaw", ()),
    ("lin_vel_w", (3,)), ("lin_vel_b", (3,)), ("ang_vel_b", (3,)), ("q", ("A",)), ("dq", ("A",)),
    ("torques", ("A",)), ("foot_force", (2, 3)), ("pen_force", ("P", 3)), ("base_height", ()),
    ("goal_vec", (2,)), ("goal_dist", ()), ("feet_xy", (2, 2)), ("foot_lift", (2,)),
)
#: The bool outputs, in order.
FLAG_FIELDS = (("contact", (2,)), ("foot_on_edge", (2,)))
#: The simulation arrays the body state is read from, (N, ...) each.
LIVE_ARRAYS = ("qpos", "qvel", "sensordata", "xpos", "actuator_force")

_vp, _i64, _f32, _f64 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_float, ctypes.c_double


class _HMap(ctypes.Structure):  # hmap_t (native/height_map.h)
    _fields_ = [("h", _vp), ("nx", _i64), ("ny", _i64), ("x0", _f32), ("y0", _f32), ("inv_res", _f32),
                ("cmax", _vp), ("cny", _i64)]


class _BodyCfg(ctypes.Structure):  # body_cfg_t (native/body_state.c)
    _fields_ = [("qpos", _vp), ("qvel", _vp), ("sensordata", _vp), ("xpos", _vp), ("act_force", _vp),
                ("qpos_stride", _i64), ("qvel_stride", _i64), ("sd_stride", _i64), ("xpos_stride", _i64),
                ("act_stride", _i64), ("qpos_adr", _vp), ("dof_adr", _vp), ("act_ids", _vp), ("A", _i64),
                ("foot_cols", _vp), ("pen_cols", _vp), ("P", _i64), ("foot_bodies", _vp), ("surface", _HMap),
                ("edge", _vp), ("enx", _i64), ("eny", _i64), ("ex0", _f64), ("ey0", _f64), ("eres", _f64),
                ("foot_rest", _f64), ("contact_thr2", _f64)]


def _row_stride(a: np.ndarray) -> int:
    """Doubles between consecutive worlds' rows of a live batch array (rows may be padded)."""
    if a.dtype != np.float64 or a.strides[0] % 8 or not a[0].flags.c_contiguous:
        raise ValueError(f"expected float64 rows, each contiguous; got dtype {a.dtype}, strides {a.strides}")
    return a.strides[0] // 8


class BodyStateReader:
    """Reads the body state of N worlds (all, or any subset of rows).

    Args:
        arrays: the simulation's live arrays :data:`LIVE_ARRAYS` (read at every call), as
            attributes (a :class:`~legoh_rl.envs.physics.BatchedWorlds`' host arrays) or a mapping
            (:attr:`~legoh_rl.envs.warp_physics.WarpWorlds.views`' tensors): all numpy or all torch.
        built: the compiled model (leg joints' addresses, feet bodies and sensors).
        terrain: the terrain lookups, on the arrays' side: a
            :class:`~legoh_rl.envs.device_terrain.HostTerrain` (or a trail source, wrapped in one)
            for numpy arrays, a :class:`~legoh_rl.envs.device_terrain.DeviceTerrain` for tensors.
            A host trail source with ``height_at_t`` (a :class:`HeightMap`) and ``edge_grid`` (edge
            mask (nx, ny), origin (x0, y0), resolution; nearest sample) is read by the native
            kernel directly.
        foot_rest_height: a standing foot body's height above the ground, m.

    :meth:`read` returns, for n = ``len(ids)`` worlds (or N): ``pos`` (n, 3) base position,
    ``rot`` (n, 3, 3) base rotation, ``gravity_b`` (n, 3) unit gravity in the base frame,
    ``roll``/``pitch``/``yaw`` (n,) rad, ``lin_vel_w``/``lin_vel_b`` (n, 3) base linear velocity in
    the world / base frame, ``ang_vel_b`` (n, 3) base angular velocity (base frame), ``q``/``dq``
    (n, A) leg joint positions / velocities, ``torques`` (n, A) actuator forces, ``foot_force``
    (n, 2, 3) and ``pen_force`` (n, P, 3) contact-sensor forces, ``contact`` (n, 2) bool (net foot
    force above 1 N), ``foot_on_edge`` (n, 2) bool (in contact on an edge sample),
    ``base_height`` (n,) m above the surface, ``goal_vec`` (n, 2) world xy to P_B, ``goal_dist``
    (n,) m, ``feet_xy`` (n, 2, 2), ``foot_lift`` (n, 2) m above the surface (0 standing). Every
    array is fresh (nothing aliases the simulation or an earlier call). The arrays are of the live
    arrays' kind and float dtype (float64 numpy on the host, float32 tensors on a device).
    """

    def __init__(self, arrays, built: BuiltModel, terrain, foot_rest_height: float) -> None:
        self.arrays = {k: arrays[k] if isinstance(arrays, Mapping) else getattr(arrays, k) for k in LIVE_ARRAYS}
        self.built = built
        self.terrain = terrain if hasattr(terrain, "heights") else HostTerrain(terrain)
        self.num_worlds = int(self.arrays["qpos"].shape[0])
        self.foot_rest_height = float(foot_rest_height)
        # sensordata columns of the feet's and the penalised bodies' contact forces, (2, 3) and (P, 3)
        self.foot_force_cols = np.array([[a + 1, a + 2, a + 3] for a in built.foot_sensor_adr], dtype=np.int64)
        self.pen_force_cols = np.array([[a + 1, a + 2, a + 3] for a in built.penalised_sensor_adr],
                                       dtype=np.int64).reshape(-1, 3)
        #: the index arrays of the Python path by name, on the arrays' side (a device's gathers
        #: take tensors there): ``qpos_adr``/``dof_adr``/``act_ids`` (A,), ``foot_bodies`` (2,),
        #: ``foot_cols`` (2, 3), ``pen_cols`` (P, 3)
        like = self.arrays["qpos"]
        xp = namespace_of(like)
        self.index = {name: np.asarray(ids, dtype=np.int64) if xp is np else
                       xp.asarray(np.asarray(ids, dtype=np.int64), device=like.device)
                       for name, ids in (("qpos_adr", built.qpos_adr), ("dof_adr", built.dof_adr),
                                         ("act_ids", built.actuator_ids), ("foot_bodies", built.foot_body_ids),
                                         ("foot_cols", self.foot_force_cols), ("pen_cols", self.pen_force_cols))}
        self.A = int(built.actuator_ids.size)
        self.P = int(self.pen_force_cols.shape[0])
        sizes = {"A": self.A, "P": self.P}
        self._float_shapes = [(name, tuple(sizes.get(d, d) for d in shape)) for name, shape in FLOAT_FIELDS]
        self._float_sizes = [int(np.prod(s)) for _, s in self._float_shapes]
        self._cfg = self._native_config()
        self._cfg_addr = None if self._cfg is None else ctypes.addressof(self._cfg)

    # ------------------------------------------------------------------ public
    @property
    def native(self) -> bool:
        """Whether :meth:`read` uses the native kernel (checked at each call: ``LEGOH_RL_NATIVE``)."""
        return self._cfg is not None and load_library() is not None

    def read(self, ids: np.ndarray | None = None, end: np.ndarray | None = None) -> dict:
        """The state of worlds ``ids`` (n,) int (rows in that order; None = all N).

        ``end`` (N, 3): each world's P_B (for ``goal_vec``/``goal_dist``); None = zeros. On a
        device, ``ids`` and ``end`` are tensors there.
        """
        lib = load_library() if self._cfg is not None else None
        if lib is None:
            return self.read_python(ids, end)
        N = self.num_worlds
        end = np.zeros((N, 3)) if end is None else end
        if end.shape != (N, 3) or end.dtype != np.float64 or not end.flags.c_contiguous:
            raise ValueError(f"end must be a C-contiguous float64 ({N}, 3) array, got {end.dtype} {end.shape}")
        if ids is None:
            n, rows = N, None
        else:
            ids = np.ascontiguousarray(ids, dtype=np.int64).reshape(-1)
            n = ids.size
            if n and (ids.min() < 0 or ids.max() >= N):
                raise ValueError(f"world ids must lie in [0, {N}), got {ids}")
            rows = ids.ctypes.data
        out = np.empty(n * sum(self._float_sizes))
        flags = np.empty(4 * n, dtype=np.uint8)
        lib.lh_body_state(self._cfg_addr, rows, n, end.ctypes.data, out.ctypes.data, flags.ctypes.data)
        state, off = {}, 0
        for (name, shape), size in zip(self._float_shapes, self._float_sizes, strict=True):
            state[name] = out[off: off + n * size].reshape((n, *shape))
            off += n * size
        flags = flags.view(bool)
        state["contact"], state["foot_on_edge"] = flags[: 2 * n].reshape(n, 2), flags[2 * n:].reshape(n, 2)
        return state

    def read_python(self, ids=None, end=None) -> dict:
        """:meth:`read` in Python over the array API: the reference (and the path of a device's
        tensors and of the host without the native library)."""
        a, ix, terrain = self.arrays, self.index, self.terrain
        xp = namespace_of(a["qpos"])
        sel = slice(None) if ids is None else ids
        qpos, qvel = a["qpos"][sel], a["qvel"][sel]
        n = qpos.shape[0]
        pos = xp.asarray(qpos[:, 0:3], copy=True)
        rot = quat_to_rotmat(qpos[:, 3:7])
        gravity_b = -rot[:, 2, :]  # world -z in the base frame = third row of R, negated
        roll, pitch = roll_pitch_from_gravity(gravity_b)
        yaw = xp.atan2(rot[:, 1, 0], rot[:, 0, 0])  # = yaw_from_quat(quat)
        lin_vel_w = xp.asarray(qvel[:, 0:3], copy=True)
        lin_vel_b = (lin_vel_w[:, None, :] @ rot)[:, 0]  # R^T v
        ang_vel_b = xp.asarray(qvel[:, 3:6], copy=True)  # free joint: angular velocity in the body frame
        sd = a["sensordata"][sel]
        foot_force = sd[:, ix["foot_cols"]]  # (n, 2, 3)
        pen_force = sd[:, ix["pen_cols"]]  # (n, P, 3)
        contact = xp.sum(foot_force * foot_force, axis=-1) > CONTACT_FORCE_THRESHOLD**2
        feet_pos = a["xpos"][sel][:, ix["foot_bodies"]]
        feet_xy = feet_pos[..., :2]
        flat_feet = xp.reshape(feet_xy, (-1, 2))
        foot_on_edge = xp.reshape(terrain.edge(flat_feet), (-1, 2))
        # terrain under the base and under each foot, one lookup: (n,) then (n, 2)
        heights = terrain.heights(xp.concat([pos[:, :2], flat_feet]))
        ground, feet_ground = heights[:n], xp.reshape(heights[n:], (-1, 2))
        goal_vec = (0.0 if end is None else end[sel, :2]) - pos[:, :2]
        return {
            "pos": pos, "rot": rot, "gravity_b": gravity_b, "roll": roll, "pitch": pitch, "yaw": yaw,
            "lin_vel_w": lin_vel_w, "lin_vel_b": lin_vel_b, "ang_vel_b": ang_vel_b,
            "q": qpos[:, ix["qpos_adr"]], "dq": qvel[:, ix["dof_adr"]],
            "torques": a["actuator_force"][sel][:, ix["act_ids"]],
            "foot_force": foot_force, "pen_force": pen_force, "contact": contact,
            "foot_on_edge": foot_on_edge & contact, "base_height": pos[:, 2] - ground,
            "goal_vec": goal_vec, "goal_dist": xp.hypot(goal_vec[:, 0], goal_vec[:, 1]),
            "feet_xy": xp.asarray(feet_xy, copy=True),
            "foot_lift": feet_pos[..., 2] - feet_ground - self.foot_rest_height,
        }

    # ------------------------------------------------------------------ native setup
    def _native_config(self) -> _BodyCfg | None:
        """The kernel's description of the arrays, or None when the trail source has no grids to
        read directly, or the arrays are not the host's float64 ones. The arrays it points into are
        kept alive by this object."""
        trails = getattr(self.terrain, "trails", None)
        surface = getattr(trails, "height_at_t", None)
        edge_grid = getattr(trails, "edge_grid", None)
        if (not isinstance(surface, HeightMap) or edge_grid is None
                or any(not isinstance(v, np.ndarray) or v.dtype != np.float64 for v in self.arrays.values())):
            return None
        w, b = self.arrays, self.built
        edge, (ex0, ey0), eres = edge_grid
        self._keep = {
            "qpos_adr": np.ascontiguousarray(b.qpos_adr, dtype=np.int64),
            "dof_adr": np.ascontiguousarray(b.dof_adr, dtype=np.int64),
            "act_ids": np.ascontiguousarray(b.actuator_ids, dtype=np.int64),
            "foot_cols": np.ascontiguousarray(self.foot_force_cols),
            "pen_cols": np.ascontiguousarray(self.pen_force_cols),
            "foot_bodies": np.ascontiguousarray(b.foot_body_ids, dtype=np.int64),
            "edge": np.ascontiguousarray(edge, dtype=np.uint8),
            "surface": surface,
        }
        k = self._keep
        nx, ny, x0, y0, inv_res = surface.grid_args
        hmap = _HMap(surface.heights.ctypes.data, nx, ny, x0, y0, inv_res, None, 0)
        arrays = tuple(w[k] for k in LIVE_ARRAYS)
        return _BodyCfg(
            *(a.ctypes.data for a in arrays), *(_row_stride(a) for a in arrays),
            k["qpos_adr"].ctypes.data, k["dof_adr"].ctypes.data, k["act_ids"].ctypes.data, self.A,
            k["foot_cols"].ctypes.data, k["pen_cols"].ctypes.data, self.P, k["foot_bodies"].ctypes.data, hmap,
            k["edge"].ctypes.data, *k["edge"].shape, float(ex0), float(ey0), float(eres),
            self.foot_rest_height, CONTACT_FORCE_THRESHOLD**2,
        )
