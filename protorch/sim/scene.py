"""The MuJoCo scene of the arm experiment, built by protorch from the task's robot description.

:func:`build_scene` reads the robot's URDF (:class:`~protorch.robots.Robot`: joints, frames and
joint limits) with ``mujoco.MjSpec`` (the compiler keeps the fixed links, e.g. the Panda's flange,
hand and tool centre point, as bodies of their own) and adds:

* every link's mass, centre of mass and inertia from the URDF's ``<inertial>`` and the robot's
  point masses (the Panda's fingers on its hand); a robot whose moving links lack them is
  refused before any work (:func:`~protorch.robots.check_inertials`);
* the robot's link capsules as the arm's collision geometry (the volumes ``collision=volume``
  plans with); the URDF's own geometry is kept without contacts or mass, its ``<visual>``
  elements (meshes resolved by :func:`protorch.robots.meshes.resolve_mesh`, converted where MuJoCo
  cannot read them whole: :mod:`protorch.robots.clean`) in geom
  group 3, which the renders show instead of the capsules where the URDF has them;
* the robot's joint damping and rotor armature, and a torque motor per joint clipped to its
  torque limits (``robot.max_torque``: the URDF's ``<limit effort>`` or its default);
* the table top (a box whose top face is ``z = 0`` under the robot and the task's table), the can
  (a cylinder of the task's radius and height on a *mocap* body: a person moves it, the arm
  cannot push it, and MuJoCo reports every contact with it) and the target (a visual marker on a
  second mocap body, no contact);
* two contact sensors reporting the number of arm-can and arm-table contacts (and the deepest
  one's distance), so that all episodes' contacts are read in one array.

The arm collides with the can and the table only (the arm's own capsules overlap at the joints by
construction; the base stands on the table), through its capsules alone: geometry of the URDF's
own (its ``<collision>`` and ``<visual>`` elements) is kept massless and without contacts, in
geom group 3. The controller's model (:func:`controller_model`)
is the same arm alone, without contacts and constraints, its link masses and inertias scaled by
``mass_scale``: the model the inverse-dynamics controller believes in.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..robots import check_inertials
from .mj import load_mujoco

__all__ = ["ArmScene", "build_scene", "hand_links", "controller_model", "ARM_BITS", "WORLD_BITS"]

ARM_BITS = (
    1,
    2,
)  # (contype, conaffinity) of the arm's capsules: they touch the world, not each other
WORLD_BITS = (2, 1)  # the table and the can
_COMPILER = (
    '<mujoco><compiler fusestatic="false" discardvisual="false" balanceinertia="false" '
    'strippath="false" '
    'meshdir="{meshdir}"/></mujoco>'
)
VISUAL_GROUP, HIDDEN_GROUP, CAPSULE_GROUP = (
    3,
    4,
    2,
)  # geom groups: the URDF's <visual>, its <collision>, the capsules
_CONTACT_SENSOR = [
    1 | 8,
    1,
    1,
]  # data: found | dist (bit flags), reduce: mindist, num: 1 -> (count, distance)
_TABLE_THICKNESS = 0.02
_CAN_RGBA = (0.75, 0.15, 0.12, 1.0)
_ARM_RGBA = (0.92, 0.92, 0.9, 1.0)
_HAND_RGBA = (0.3, 0.3, 0.32, 1.0)


@dataclass
class ArmScene:
    """A compiled scene: ``model``, the arm's joints in order (``qpos`` / ``qvel`` indices), the
    mocap indices of the can and the target, the sensor addresses of the arm-can and arm-table
    contact counts, the torque limits ``(J,)`` and the task it was built for."""

    model: Any  # mujoco.MjModel
    qpos_index: np.ndarray  # (J,)
    can_mocap: int
    target_mocap: int
    can_contact: (
        int  # sensordata index: number of arm-can contacts (the next entry: the deepest's distance)
    )
    table_contact: int
    torque_limits: np.ndarray  # (J,)
    task: object
    visuals: bool = (
        False  # the URDF has <visual> geometry: renders show it (group 3), not the capsules
    )

    @property
    def timestep(self) -> float:
        return float(self.model.opt.timestep)


def hand_links(task) -> set[str]:
    """The links rigid with the end link beyond the last joint's own link (the Panda's flange, hand
    and tool centre point): drawn in the hand's colour."""
    kin = task.kinematics
    out = set()
    for name in reversed(kin.frame_names[1:]):
        if kin.chain.find_frame(name).joint.joint_type != "fixed":
            break
        out.add(name)
    return out


def _arm_spec(task, mass_scale: float, timestep: float):
    """The task's robot from its URDF with its inertials, capsules, damping, armature and motors."""
    mujoco = load_mujoco()
    robot = task.robot
    check_inertials(robot)
    folder = Path(robot.urdf).parent
    text = robot.urdf_text  # mesh paths resolved, off-chain joints locked (protorch.robots.clean)
    head = text.index(">", text.index("<robot")) + 1
    spec = mujoco.MjSpec.from_string(
        text[:head] + _COMPILER.format(meshdir=f"{folder}/") + text[head:]
    )
    spec.option.timestep = float(timestep)
    visuals = False
    for (
        geom
    ) in spec.geoms:  # the URDF's own geometry: no contact, no mass (the capsules collide); its
        visual = (
            geom.contype == 0 and geom.conaffinity == 0
        )  # <visual> shown by the renders, <collision> never
        visuals |= visual
        geom.contype, geom.conaffinity, geom.density = 0, 0, 0.0
        geom.group = VISUAL_GROUP if visual else HIDDEN_GROUP
    frames = set(task.kinematics.frame_names)
    for name, inertial in robot.inertials.items():
        if name not in frames:
            continue
        body = spec.body(name)
        body.mass = inertial.mass * mass_scale
        body.ipos = list(inertial.com)
        body.fullinertia = [v * mass_scale for v in inertial.inertia]
        body.explicitinertial = True
    for pm in robot.point_masses:
        point = spec.body(pm.link).add_body(pos=list(pm.pos))
        point.mass, point.explicitinertial = pm.mass * mass_scale, True
        point.inertia = [v * mass_scale for v in pm.inertia]
    hand = hand_links(task)
    for c in robot.capsule_list():
        rgba = _HAND_RGBA if c.link in hand else _ARM_RGBA
        if c.a == c.b:  # a capsule of length 0: MuJoCo takes it as a sphere
            shape = dict(type=mujoco.mjtGeom.mjGEOM_SPHERE, pos=list(c.a))
        else:
            shape = dict(type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=[*c.a, *c.b])
        spec.body(c.link).add_geom(
            **shape,
            size=[c.radius, 0, 0],
            contype=ARM_BITS[0],
            conaffinity=ARM_BITS[1],
            rgba=list(rgba),
            group=CAPSULE_GROUP if visuals else 0,
        )
    names = task.kinematics.joint_names
    for i, name in enumerate(names):
        joint = spec.joint(name)
        joint.armature = robot.armature[i]
        joint.damping[0] = robot.damping[i]
        lim = robot.max_torque[i]
        spec.add_actuator(
            name=f"motor{i + 1}",
            target=name,
            trntype=mujoco.mjtTrn.mjTRN_JOINT,
            gainprm=[1.0] + [0.0] * 9,
            forcelimited=True,
            forcerange=[-lim, lim],
            ctrllimited=False,
        )
    return spec


def _look_at(pos, target) -> list[float]:
    """A camera's ``xyaxes`` at ``pos`` looking at ``target``, the image upright."""
    f = np.subtract(target, pos, dtype=np.float64)
    f /= np.linalg.norm(f)
    x = np.cross(f, (0.0, 0.0, 1.0))
    x /= np.linalg.norm(x)
    return [*x.tolist(), *np.cross(x, f).tolist()]


def _add_world(spec, task) -> None:
    """The table, the can, the target, the contact sensors, a light and a camera."""
    mujoco = load_mujoco()
    world = spec.worldbody
    (x0, x1), (y0, y1) = task.table
    lo_x, hi_x, lo_y, hi_y = min(x0, -0.25), max(x1, 0.2), min(y0, -0.3), max(y1, 0.3)
    world.add_geom(
        name="table",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        rgba=[0.62, 0.5, 0.38, 1.0],
        size=[(hi_x - lo_x) / 2, (hi_y - lo_y) / 2, _TABLE_THICKNESS / 2],
        pos=[(hi_x + lo_x) / 2, (hi_y + lo_y) / 2, -_TABLE_THICKNESS / 2],
        contype=WORLD_BITS[0],
        conaffinity=WORLD_BITS[1],
    )
    for link in task.robot.base_links:
        spec.add_exclude(bodyname1="world", bodyname2=link)
    can = world.add_body(name="can", mocap=True, pos=[0.6, 0.0, task.can_height / 2])
    can.add_geom(
        name="can",
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        size=[task.can_radius, task.can_height / 2, 0],
        contype=WORLD_BITS[0],
        conaffinity=WORLD_BITS[1],
        rgba=list(_CAN_RGBA),
    )
    target = world.add_body(name="target", mocap=True, pos=[0.7, 0.0, task.ee_height])
    target.add_geom(
        name="target",
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[0.015, 0, 0],
        contype=0,
        conaffinity=0,
        rgba=[0.1, 0.75, 0.2, 0.8],
    )
    world.add_light(pos=[0.4, -0.6, 1.6], dir=[0.0, 0.35, -1.0], diffuse=[0.7, 0.7, 0.7])
    spec.add_texture(
        name="sky",
        type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
        rgb1=[0.85, 0.9, 0.95],
        rgb2=[0.45, 0.5, 0.55],
        width=256,
        height=256,
    )
    world.add_camera(
        name="front",
        pos=[0.25, -0.95, 1.55],
        xyaxes=_look_at((0.25, -0.95, 1.55), (0.62, 0.05, 0.05)),
    )
    world.add_camera(name="top", pos=[0.5, 0.0, 1.6], xyaxes=[0.0, 1.0, 0.0, -1.0, 0.0, 0.0])
    root = task.kinematics.frame_names[1]  # the first moving link: its subtree is the arm
    for name, other in (("arm_can", "can"), ("arm_table", "world")):
        spec.add_sensor(
            name=name,
            type=mujoco.mjtSensor.mjSENS_CONTACT,
            objtype=mujoco.mjtObj.mjOBJ_XBODY,
            objname=root,
            reftype=mujoco.mjtObj.mjOBJ_BODY,
            refname=other,
            intprm=_CONTACT_SENSOR,
        )


def build_scene(task, *, timestep: float = 0.002, mass_scale: float = 1.0) -> ArmScene:
    """The plant (module docstring) for an :class:`~protorch.tasks.ArmReachTask` with its robot;
    ``timestep`` is MuJoCo's step (s)."""
    load_mujoco()  # one line naming the extra where MuJoCo is missing
    spec = _arm_spec(task, mass_scale, timestep)
    _add_world(spec, task)
    spec.visual.global_.offwidth, spec.visual.global_.offheight = 960, 720
    model = spec.compile()
    names = task.kinematics.joint_names
    qpos_index = np.array([model.jnt_qposadr[model.joint(n).id] for n in names])
    if not np.array_equal(qpos_index, np.arange(len(names))) or model.nv != len(names):
        raise ValueError(f"the scene's joints {names} are not the model's only degrees of freedom")
    return ArmScene(
        model=model,
        qpos_index=qpos_index,
        can_mocap=int(model.body("can").mocapid[0]),
        target_mocap=int(model.body("target").mocapid[0]),
        can_contact=int(model.sensor("arm_can").adr[0]),
        table_contact=int(model.sensor("arm_table").adr[0]),
        torque_limits=np.array(task.robot.max_torque, dtype=np.float64),
        task=task,
        visuals=bool((model.geom_group == VISUAL_GROUP).any()),
    )


def controller_model(task, *, timestep: float = 0.002, mass_scale: float = 1.0):
    """The arm alone (no table, can, contacts or constraints), link masses and inertias times
    ``mass_scale``: what the controller computes ``M(q)`` and the bias forces with."""
    mujoco = load_mujoco()
    model = _arm_spec(task, mass_scale, timestep).compile()
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(
        mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    )
    return model
