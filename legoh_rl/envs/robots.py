"""Unitree H1 and G1: robot registry and MuJoCo model building.

A :class:`RobotSpec` holds everything the env needs to know about a robot: its leg joints in a
fixed order (the order of actions and of every per-joint observation), the default pose, the PD
gains and torque limits, the bodies that matter (base, torso, feet, bodies whose contacts are
penalised), the head depth camera mount and the target base height. The reward weights that differ
per robot are declared with their terms (``per_robot`` in :mod:`legoh_rl.envs.rewards`).

:func:`build_model` rebuilds the MuJoCo Menagerie model with :class:`mujoco.MjSpec`:

* every upper-body joint is deleted, which welds the upper body to the pelvis at its default pose
  (the paper freezes the upper body) and shrinks the state (H1: nv 16, G1: nv 18);
* the Menagerie actuators are replaced by one MuJoCo *position* actuator per leg joint with the
  Unitree gains (kp, kv=Kd) and force-limited to the motor torque range, so the PD law
  ``tau = Kp (q* - q) - Kd dq`` acts at every physics substep, not once per policy step;
* a forward-facing head depth camera and contact sensors (feet, penalised bodies) are added;
* robot geoms are put in collision class ``contype=2, conaffinity=1``: they touch the terrain
  (MuJoCo's default ``1/1``) but not each other, which is cheaper and stable;
* G1's 5 mm sole spheres are grown to 20 mm with the sole kept in place
  (:attr:`RobotSpec.foot_sphere_radius`), so a landing foot does not sink its spheres' centres
  below the heightfield's surface;
* the terrain comes from a :class:`TerrainBuilder` (the trail grid), or a flat plane.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import mujoco
import numpy as np

__all__ = [
    "RobotSpec",
    "BuiltModel",
    "TerrainBuilder",
    "ROBOTS",
    "get_robot_spec",
    "resolve_model_dir",
    "build_model",
    "ROBOT_CONTYPE",
    "ROBOT_CONAFFINITY",
    "ROBOT_GEOM_GROUPS",
    "TERRAIN_GEOM_GROUPS",
    "GROUND_GEOM_GROUP",
    "OBSTACLE_GEOM_GROUP",
]

ROBOT_CONTYPE = 2
ROBOT_CONAFFINITY = 1
# (visual, collision) geom groups of the robot; the terrain uses groups 0 and 1.
ROBOT_GEOM_GROUPS = (2, 3)
TERRAIN_GEOM_GROUPS = (0, 1)
# within the terrain: group 0 = the ground (heightfield / plane), group 1 = obstacles
GROUND_GEOM_GROUP, OBSTACLE_GEOM_GROUP = TERRAIN_GEOM_GROUPS


@dataclass(frozen=True)
class RobotSpec:
    """Static description of one humanoid.

    Attributes:
        name: registry name (``"h1"`` or ``"g1"``).
        menagerie_name: folder / registry name in MuJoCo Menagerie.
        xml_file: robot file inside that folder (without the scene).
        leg_joints: actuated joint names, (A,), in action order: left leg then right leg.
        default_joint_pos: q_default, (A,) rad.
        kp: proportional gains, (A,) N m / rad.
        kd: derivative gains, (A,) N m s / rad.
        torque_limits: |tau| bounds, (A,) N m.
        hip_joints: names of the hip yaw/roll joints penalised by the hip-position reward.
        base_body: floating base body (free joint).
        torso_body: torso body (upper body, frozen).
        foot_bodies: (left, right) foot bodies.
        penalised_bodies: bodies whose contacts count as collisions; ``name`` means the body
            alone, ``name/`` its whole subtree.
        camera_body: body the head camera is attached to.
        camera_pos: camera position in ``camera_body``'s frame, (3,) m.
        camera_pitch_deg: downward pitch of the camera's optical axis, degrees.
        camera_fovy_deg: vertical (= horizontal, square image) field of view, degrees.
        base_height_target: target pelvis height for the base-height reward, m.
        spawn_height: pelvis height above the ground at spawn, m (default pose, feet just clear).
        foot_rest_height: height of a foot body's origin above flat ground when the robot stands
            on it, m (measured in simulation; the zero of the clearance reward's foot lift).
        action_scale: q* = q_default + action_scale * action.
        foot_sphere_radius: radius given to the sphere colliders of the foot bodies, m, their
            centres raised by the growth so the sole plane (and ``foot_rest_height``) stays where
            the model put it; ``None`` keeps the model's spheres. G1's Menagerie soles are four
            5 mm spheres, which sink up to 16 mm into the heightfield when a foot lands: with its
            centre under the surface, C MuJoCo resolves a sphere against the heightfield's prism
            walls (sideways normals, the foot caught) and MuJoCo Warp against its top (upward),
            so the same gait stands on one backend and falls on the other
            (docs/history/g1-foot-contacts.md).
    """

    name: str
    menagerie_name: str
    xml_file: str
    leg_joints: tuple[str, ...]
    default_joint_pos: tuple[float, ...]
    kp: tuple[float, ...]
    kd: tuple[float, ...]
    torque_limits: tuple[float, ...]
    hip_joints: tuple[str, ...]
    base_body: str
    torso_body: str
    foot_bodies: tuple[str, str]
    penalised_bodies: tuple[str, ...]
    camera_body: str
    camera_pos: tuple[float, float, float]
    camera_pitch_deg: float
    camera_fovy_deg: float
    base_height_target: float
    spawn_height: float
    foot_rest_height: float
    action_scale: float = 0.25
    foot_sphere_radius: float | None = None

    def __post_init__(self) -> None:
        if self.foot_sphere_radius is not None and not (
            math.isfinite(self.foot_sphere_radius) and self.foot_sphere_radius > 0.0
        ):
            raise ValueError(f"RobotSpec {self.name!r}: foot_sphere_radius must be a positive length in m or None, "
                             f"got {self.foot_sphere_radius!r}")
        n = len(self.leg_joints)
        for attr in ("default_joint_pos", "kp", "kd", "torque_limits"):
            if len(getattr(self, attr)) != n:
                raise ValueError(
                    f"RobotSpec {self.name!r}: {attr} has {len(getattr(self, attr))} values, "
                    f"expected one per leg joint ({n})"
                )

    @property
    def num_actions(self) -> int:
        """A, the number of actuated leg joints."""
        return len(self.leg_joints)


def _legs(per_leg: list[str], fmt: str) -> tuple[str, ...]:
    return tuple(fmt.format(side=side, j=j) for side in ("left", "right") for j in per_leg)


_H1 = RobotSpec(
    name="h1",
    menagerie_name="unitree_h1",
    xml_file="h1.xml",
    leg_joints=_legs(["hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle"], "{side}_{j}"),
    default_joint_pos=(0.0, 0.0, -0.1, 0.3, -0.2) * 2,
    kp=(150.0, 150.0, 150.0, 200.0, 40.0) * 2,
    kd=(2.0, 2.0, 2.0, 4.0, 2.0) * 2,
    torque_limits=(200.0, 200.0, 200.0, 300.0, 40.0) * 2,
    hip_joints=("left_hip_yaw", "left_hip_roll", "right_hip_yaw", "right_hip_roll"),
    base_body="pelvis",
    torso_body="torso_link",
    foot_bodies=("left_ankle_link", "right_ankle_link"),
    penalised_bodies=(
        "pelvis",
        "torso_link/",
        "left_hip_yaw_link",
        "left_hip_roll_link",
        "left_hip_pitch_link",
        "left_knee_link",
        "right_hip_yaw_link",
        "right_hip_roll_link",
        "right_hip_pitch_link",
        "right_knee_link",
    ),
    camera_body="torso_link",
    camera_pos=(0.10, 0.0, 0.68),
    camera_pitch_deg=45.0,
    camera_fovy_deg=58.0,
    base_height_target=1.05,
    spawn_height=1.04,
    foot_rest_height=0.065,
)

_G1 = RobotSpec(
    name="g1",
    menagerie_name="unitree_g1",
    xml_file="g1.xml",
    leg_joints=_legs(
        ["hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch", "ankle_roll"], "{side}_{j}_joint"
    ),
    default_joint_pos=(-0.1, 0.0, 0.0, 0.3, -0.2, 0.0) * 2,
    kp=(100.0, 100.0, 100.0, 150.0, 40.0, 40.0) * 2,
    kd=(2.0, 2.0, 2.0, 4.0, 2.0, 2.0) * 2,
    torque_limits=(88.0, 139.0, 88.0, 139.0, 50.0, 50.0) * 2,
    hip_joints=("left_hip_yaw_joint", "left_hip_roll_joint", "right_hip_yaw_joint", "right_hip_roll_joint"),
    base_body="pelvis",
    torso_body="torso_link",
    foot_bodies=("left_ankle_roll_link", "right_ankle_roll_link"),
    penalised_bodies=(
        "pelvis",
        "waist_yaw_link/",
        "left_hip_pitch_link",
        "left_hip_roll_link",
        "left_hip_yaw_link",
        "left_knee_link",
        "right_hip_pitch_link",
        "right_hip_roll_link",
        "right_hip_yaw_link",
        "right_knee_link",
    ),
    camera_body="torso_link",
    camera_pos=(0.08, 0.0, 0.43),
    camera_pitch_deg=45.0,
    camera_fovy_deg=58.0,
    base_height_target=0.78,
    spawn_height=0.80,
    foot_rest_height=0.035,
    foot_sphere_radius=0.02,
)

ROBOTS: dict[str, RobotSpec] = {"h1": _H1, "g1": _G1}


def get_robot_spec(name: str, freeze_ankle_roll: bool = False) -> RobotSpec:
    """The :class:`RobotSpec` of a registered robot.

    Args:
        name: ``"h1"`` or ``"g1"`` (case-insensitive).
        freeze_ankle_roll: G1 only: drop the two ankle-roll joints from the actions (they are
            welded at 0), giving the paper's 10 actions. H1 has no ankle roll.

    Raises:
        ValueError: unknown robot name (the message lists the known ones), or
            ``freeze_ankle_roll`` asked of a robot without ankle-roll joints.
    """
    key = str(name).lower()
    if key not in ROBOTS:
        raise ValueError(f"unknown robot {name!r}; known robots: {sorted(ROBOTS)}")
    spec = ROBOTS[key]
    if not freeze_ankle_roll:
        return spec
    keep = [i for i, j in enumerate(spec.leg_joints) if "ankle_roll" not in j]
    if len(keep) == spec.num_actions:
        raise ValueError(f"robot {name!r} has no ankle-roll joints to freeze")

    def pick(values: tuple) -> tuple:
        return tuple(values[i] for i in keep)

    return RobotSpec(
        **{
            **spec.__dict__,
            "name": f"{spec.name}_10dof",
            "leg_joints": pick(spec.leg_joints),
            "default_joint_pos": pick(spec.default_joint_pos),
            "kp": pick(spec.kp),
            "kd": pick(spec.kd),
            "torque_limits": pick(spec.torque_limits),
        }
    )


def resolve_model_dir(spec: RobotSpec) -> Path:
    """Folder holding the robot's Menagerie files.

    Offline: ``$MENAGERIE_ROOT/<menagerie_name>/``. Online: the ``mujoco-menagerie`` package's
    cache, downloading on first use.

    Raises:
        FileNotFoundError: the folder is missing; the message says where it looked and how to fix.
    """
    root = os.environ.get("MENAGERIE_ROOT")
    if root:
        path = Path(root).expanduser() / spec.menagerie_name
        if not (path / spec.xml_file).is_file():
            raise FileNotFoundError(
                f"robot model for {spec.name!r} not found: looked for {path / spec.xml_file} "
                f"(MENAGERIE_ROOT={root}). Point MENAGERIE_ROOT at a folder holding "
                f"'{spec.menagerie_name}/', or unset it to let the mujoco-menagerie package "
                "download the model (needs network)."
            )
        return path
    try:
        import mujoco_menagerie

        return Path(mujoco_menagerie.get(spec.menagerie_name).path(progress=None))
    except Exception as err:  # download or registry failure: say what to do
        raise FileNotFoundError(
            f"robot model for {spec.name!r} ({spec.menagerie_name}) could not be obtained from the "
            f"mujoco-menagerie package ({type(err).__name__}: {err}). Offline, set MENAGERIE_ROOT "
            f"to a folder holding '{spec.menagerie_name}/' (this repository's CI uses "
            "../shared/robots)."
        ) from err


class TerrainBuilder(Protocol):
    """Anything that adds static terrain to a model spec: the ground (heightfield or plane) in
    geom group 0 and obstacles in group 1 (the depth camera relies on this split)."""

    def add_to_spec(self, spec: mujoco.MjSpec) -> None:
        """Add the terrain to ``spec.worldbody``."""


@dataclass
class BuiltModel:
    """A compiled robot + terrain model and the indices the env reads it through.

    Attributes:
        model: the compiled :class:`mujoco.MjModel`.
        robot: the :class:`RobotSpec` it was built from.
        qpos_adr: leg joint qpos addresses, (A,) int.
        dof_adr: leg joint dof addresses, (A,) int.
        joint_range: leg joint limits, (A, 2) rad.
        actuator_ids: position actuator per leg joint, (A,) int (ctrl columns, action order).
        base_body_id: floating base body id.
        torso_body_id: torso body id.
        foot_body_ids: (2,) foot body ids.
        robot_body_ids: every body of the robot, (nb,) int.
        robot_geom_ids: every geom of the robot, (ng,) int.
        camera_id: head depth camera id.
        foot_sensor_adr: sensordata address of each foot's contact sensor, (2,) int; each sensor
            is 4 numbers: contact count, then the net contact force (3,).
        penalised_sensor_adr: same for each penalised body, (P,) int.
        hip_idx: positions of the hip yaw/roll joints within the leg joints, (4,) int.
        default_qpos: full qpos of the robot standing at its default pose at the origin, (nq,).
    """

    model: mujoco.MjModel
    robot: RobotSpec
    qpos_adr: np.ndarray
    dof_adr: np.ndarray
    joint_range: np.ndarray
    actuator_ids: np.ndarray
    base_body_id: int
    torso_body_id: int
    foot_body_ids: np.ndarray
    robot_body_ids: np.ndarray
    robot_geom_ids: np.ndarray
    camera_id: int
    foot_sensor_adr: np.ndarray
    penalised_sensor_adr: np.ndarray
    hip_idx: np.ndarray
    default_qpos: np.ndarray


CAMERA_NAME = "head_depth"


def _camera_quat(pitch_deg: float) -> np.ndarray:
    """Camera orientation looking along the body's +x, pitched down by ``pitch_deg``.

    A MuJoCo camera looks along its -z axis with +y up. The level camera has axes
    x_cam = -y_body, y_cam = +z_body, z_cam = -x_body; pitching down rotates that frame about
    the body y axis.
    """
    level = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # columns = cam axes
    p = math.radians(pitch_deg)
    rot_y = np.array([[math.cos(p), 0.0, math.sin(p)], [0.0, 1.0, 0.0], [-math.sin(p), 0.0, math.cos(p)]])
    mat = rot_y @ level
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, mat.flatten())
    return quat


def _add_contact_sensor(spec: mujoco.MjSpec, name: str, body: str) -> None:
    subtree = body.endswith("/")
    sensor = spec.add_sensor()
    sensor.name = name
    sensor.type = mujoco.mjtSensor.mjSENS_CONTACT
    sensor.objtype = mujoco.mjtObj.mjOBJ_XBODY if subtree else mujoco.mjtObj.mjOBJ_BODY
    sensor.objname = body.rstrip("/")
    sensor.intprm[:3] = [3, 3, 1]  # data = found|force, reduce = netforce, num = 1


def build_model(
    robot: RobotSpec | str,
    terrain: TerrainBuilder | None = None,
    timestep: float = 0.005,
    model_dir: str | os.PathLike | None = None,
    visual: Callable[[mujoco.MjSpec], None] | None = None,
) -> BuiltModel:
    """Build the robot (upper body frozen, PD leg actuators, head camera) on a terrain.

    Args:
        robot: a :class:`RobotSpec` or a registry name.
        terrain: adds the ground (see :class:`TerrainBuilder`); ``None`` adds a flat plane.
        timestep: physics timestep, s.
        model_dir: folder with the Menagerie files; default :func:`resolve_model_dir`.
        visual: called with the finished spec just before it is compiled, for changes that only
            drawing sees (textures, materials, colours, lights' looks; the renderer's model,
            :func:`legoh_rl.envs.render.build_render_model`). It must not add or remove bodies,
            joints, lights or cameras: the renderer copies states of the physics model into the
            model it builds.

    Returns:
        The :class:`BuiltModel`.
    """
    if isinstance(robot, str):
        robot = get_robot_spec(robot)
    if not (timestep > 0.0 and math.isfinite(timestep)):
        raise ValueError(f"timestep must be a positive number of seconds, got {timestep!r}")
    folder = Path(model_dir) if model_dir is not None else resolve_model_dir(robot)
    spec = mujoco.MjSpec.from_file(str(folder / robot.xml_file))
    spec.modelname = f"legoh_{robot.name}"

    for key in list(spec.keys):
        spec.delete(key)
    for act in list(spec.actuators):
        spec.delete(act)
    legs = set(robot.leg_joints)
    known = {j.name for j in spec.joints}
    missing = legs - known
    if missing:
        raise ValueError(f"robot {robot.name!r}: joints {sorted(missing)} are not in {folder / robot.xml_file}")
    for joint in list(spec.joints):
        if joint.type != mujoco.mjtJoint.mjJNT_FREE and joint.name not in legs:
            spec.delete(joint)  # welds the body to its parent at the default (zero) angle

    spec.option.timestep = timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL

    for geom in spec.geoms:
        collides = bool(geom.contype or geom.conaffinity)
        if collides:
            geom.contype = ROBOT_CONTYPE
            geom.conaffinity = ROBOT_CONAFFINITY
            geom.condim = 3
            geom.priority = 1  # contact friction = the robot's (randomised per world)
        # groups 0-1 belong to the terrain (what the depth camera sees), 2-3 to the robot
        if geom.group < ROBOT_GEOM_GROUPS[0]:
            geom.group = ROBOT_GEOM_GROUPS[1] if collides else ROBOT_GEOM_GROUPS[0]

    if robot.foot_sphere_radius is not None:
        _grow_foot_spheres(spec, robot.foot_bodies, robot.foot_sphere_radius)

    for name, kp, kd, tau in zip(robot.leg_joints, robot.kp, robot.kd, robot.torque_limits, strict=True):
        act = spec.add_actuator()
        act.name = name
        act.target = name
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.set_to_position(kp=kp, kv=kd)
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-tau, tau]

    cam_parent = spec.body(robot.camera_body)
    cam = cam_parent.add_camera()
    cam.name = CAMERA_NAME
    cam.pos = list(robot.camera_pos)
    cam.quat = list(_camera_quat(robot.camera_pitch_deg))
    cam.fovy = robot.camera_fovy_deg

    for side, body in zip(("left", "right"), robot.foot_bodies, strict=True):
        _add_contact_sensor(spec, f"contact_foot_{side}", body)
    for body in robot.penalised_bodies:
        _add_contact_sensor(spec, f"contact_pen_{body.rstrip('/')}", body)

    robot_body_names = {b.name for b in spec.bodies if b.name and b.name != "world"}
    if terrain is None:
        floor = spec.worldbody.add_geom()
        floor.name = "terrain_floor"
        floor.type = mujoco.mjtGeom.mjGEOM_PLANE
        floor.size = [0.0, 0.0, 0.05]
        floor.friction = [1.0, 0.005, 0.0001]
    else:
        terrain.add_to_spec(spec)
    spec.worldbody.add_light(pos=[0, 0, 6], dir=[0, 0, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)
    if visual is not None:
        visual(spec)

    model = spec.compile()
    return _index(model, robot, robot_body_names)


def _grow_foot_spheres(spec: mujoco.MjSpec, foot_bodies: tuple[str, str], radius: float) -> None:
    """Give every colliding sphere of ``foot_bodies`` the ``radius`` (m), its centre raised along
    the body's z by the growth so its lowest point, the sole, stays put.

    Raises:
        ValueError: a foot body has no colliding sphere, or one is larger than ``radius``.
    """
    for name in foot_bodies:
        spheres = [g for g in spec.body(name).geoms
                   if g.type == mujoco.mjtGeom.mjGEOM_SPHERE and (g.contype or g.conaffinity)]
        if not spheres:
            raise ValueError(f"foot_sphere_radius is set but foot body {name!r} has no colliding sphere")
        for geom in spheres:
            grow = radius - float(geom.size[0])
            if grow < 0.0:
                raise ValueError(f"foot_sphere_radius {radius} m is below foot body {name!r}'s sphere radius "
                                 f"{geom.size[0]} m: the spheres are only grown")
            geom.size = [radius, 0.0, 0.0]
            geom.pos = [geom.pos[0], geom.pos[1], geom.pos[2] + grow]


def _index(model: mujoco.MjModel, robot: RobotSpec, robot_body_names: set[str]) -> BuiltModel:
    jids = [model.joint(n).id for n in robot.leg_joints]
    body_ids = np.array(sorted(model.body(n).id for n in robot_body_names), dtype=np.int64)
    geom_ids = np.flatnonzero(np.isin(model.geom_bodyid, body_ids))
    sensor_adr = {model.sensor(i).name: int(model.sensor_adr[i]) for i in range(model.nsensor)}
    base = model.body(robot.base_body).id
    default_qpos = model.qpos0.copy()
    default_qpos[model.jnt_qposadr[model.body_jntadr[base]] + 2] = robot.spawn_height
    default_qpos[[model.jnt_qposadr[j] for j in jids]] = robot.default_joint_pos
    return BuiltModel(
        model=model,
        robot=robot,
        qpos_adr=np.array([model.jnt_qposadr[j] for j in jids], dtype=np.int64),
        dof_adr=np.array([model.jnt_dofadr[j] for j in jids], dtype=np.int64),
        joint_range=np.array([model.jnt_range[j] for j in jids], dtype=np.float64),
        actuator_ids=np.array([model.actuator(n).id for n in robot.leg_joints], dtype=np.int64),
        base_body_id=base,
        torso_body_id=model.body(robot.torso_body).id,
        foot_body_ids=np.array([model.body(n).id for n in robot.foot_bodies], dtype=np.int64),
        robot_body_ids=body_ids,
        robot_geom_ids=geom_ids,
        camera_id=model.camera(CAMERA_NAME).id,
        foot_sensor_adr=np.array([sensor_adr[f"contact_foot_{s}"] for s in ("left", "right")]),
        penalised_sensor_adr=np.array(
            [sensor_adr[f"contact_pen_{b.rstrip('/')}"] for b in robot.penalised_bodies]
        ),
        hip_idx=np.array([robot.leg_joints.index(j) for j in robot.hip_joints], dtype=np.int64),
        default_qpos=default_qpos,
    )
