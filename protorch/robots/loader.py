"""Robot descriptions from settings: :func:`load_robot` (a shipped name, a plain dict of
``robot.*`` settings, or a :class:`~protorch.robots.Robot`) and the checks every bad input gets,
each a :class:`RobotError` of one line naming the setting, before any work.

The settings (``conf/robot/*.yaml``; docs/your_own_robot.md; every key optional but ``urdf``,
``end_link`` and ``home`` without a ``base``):

==================  ============================================================================
``base``            a shipped description (``protorch/robots/<base>.yaml``, e.g. ``panda``) the
                    other keys override; null: none
``name``            display name (figure titles, metrics.json); null: the URDF's ``<robot name>``
``urdf``            the URDF file (relative: to the working directory; in a shipped yaml, to it)
``mjcf``            instead of ``urdf``: an MJCF (MuJoCo) file, converted once to a URDF
                    (:mod:`protorch.robots.mjcf`)
``end_link``        the chain's last link, the tool centre point
``home``            the start configuration, one angle (rad) per joint of the chain
``max_velocity``    rad/s, a number or one per joint; null: the URDF's ``<limit velocity>``
``max_acceleration`` rad/s^2, a number or one per joint (default 10)
``max_jerk``        rad/s^3, a number or one per joint: what a policy's reference may ask in a
                    control loop (:mod:`protorch.policy.limits`); null: 7,500 (Franka's published
                    limit, the Panda's)
``max_torque``      N m, a number or one per joint; null: the URDF's ``<limit effort>``
``damping``         joint damping, N m s / rad, a number or one per joint (default 1.0)
``armature``        rotor armature, kg m^2, a number or one per joint (default 0.1)
``capsules``        the collision volumes: ``auto`` (fitted to the URDF's ``<collision>``
                    geometry, :mod:`protorch.robots.capsules`), ``none``, or ``{link: [{a: [x, y,
                    z], b:
                    [x, y, z], radius: r}, ...]}`` in the link frames (m)
``forearm_link``    a link whose capsules the volume objective reads besides those rigid with the
                    end link (the Panda: link 5, which passes over the can); null: none; ``auto``
                    (the default): the link the third moving joint from the end moves
``base_links``      links fixed to the table (no table check); ``auto``: the chain's links before
                    its first joint
``point_masses``    ``[{link, pos: [x, y, z], mass, inertia: [ixx, iyy, izz]}]``: bodies the URDF
                    lacks (the Panda's fingers)
``packages``        folders where ``package://NAME/...`` meshes are looked up after the URDF's own
                    folders and ``ROS_PACKAGE_PATH`` (:mod:`protorch.robots.meshes`)
``locked``          ``{joint: value}``: joints off the chain held at a value other than 0
``limits``          ``{joint: [lower, upper]}``: limits of ``continuous`` joints (default +-pi)
``balance_inertia`` true: inertias violating ``A + B >= C`` are balanced with a warning; false:
                    refused
==================  ============================================================================

``end_link`` null: the leaf link reached through the most moving joints (refused, listing the
candidates, where several tie). ``home`` null: found by the hand-down inverse kinematics
(:func:`protorch.robots.layout.hand_down_layout`; the pose, residual and seed reported in
:attr:`Robot.found`). The file is read as it comes (:func:`protorch.robots.clean.clean_urdf`:
XML declaration, unused tags, off-chain joints, continuous joints, inertias, meshes).

A joint without ``<limit lower upper>`` (other than ``continuous``) is refused naming the joint.
A velocity or effort limit missing, not positive, or implausible (a velocity above
:data:`MAX_PLAUSIBLE_VELOCITY`) that no setting gives is replaced by :data:`DEFAULT_VELOCITY` /
:data:`DEFAULT_EFFORT` with a warning naming the joints (reported in :attr:`Robot.found`).
"""

from __future__ import annotations

import json
import logging
import math
import numbers
import xml.etree.ElementTree as ET
from pathlib import Path

from .clean import CleanError, clean_urdf, end_link_candidates, urdf_chain
from .description import Robot
from .kinematics import ArmKinematics
from .layout import hand_down_layout, hand_drop
from .mjcf import MjcfError, mjcf_urdf
from .parts import (
    RobotError,
    auto_capsules,
    capsules_setting,
    joint_vector,
    point_masses_setting,
    urdf_inertials,
)
from .urdf import ROBOTS_DIR, parse_urdf, shipped_yaml

log = logging.getLogger(__name__)

__all__ = [
    "RobotError",
    "ROBOTS_DIR",
    "SETTINGS",
    "DEFAULTS",
    "shipped_robots",
    "load_robot",
    "robot_settings",
    "urdf_inertials",
    "check_inertials",
    "auto_capsules",
    "MIN_JOINTS",
]

MIN_JOINTS = 6  # a hand-down pose at every point of the workspace needs six joints
DEFAULT_VELOCITY = 2.0  # rad/s: a joint's speed where the URDF gives none (or an implausible one)
DEFAULT_EFFORT = 50.0  # N m: a joint's torque where the URDF gives none
DEFAULT_JERK = 7500.0  # rad/s^3: Franka's published jerk limit, where a robot states none
MAX_PLAUSIBLE_VELOCITY = 2 * math.pi  # rad/s: a revolution a second, beyond any arm's rating
DEFAULTS = {
    "base": None,
    "name": None,
    "urdf": None,
    "mjcf": None,
    "end_link": None,
    "home": None,
    "max_velocity": None,
    "max_acceleration": 10.0,
    "max_jerk": None,
    "max_torque": None,
    "damping": 1.0,
    "armature": 0.1,
    "capsules": "auto",
    "forearm_link": "auto",
    "base_links": "auto",
    "point_masses": [],
    "packages": [],
    "locked": {},
    "limits": {},
    "balance_inertia": True,
}
SETTINGS = {
    "base": "a shipped description (protorch/robots/<base>.yaml) the other keys override; null: "
    "none",
    "name": "display name (figure titles, metrics.json); null: the URDF's <robot name>",
    "urdf": "the arm's URDF file",
    "mjcf": "the arm's MJCF (MuJoCo) file, instead of robot.urdf",
    "end_link": "the chain's last link: the tool centre point",
    "home": "the start configuration, one angle (rad) per joint",
    "max_velocity": "rad/s, a number or one per joint; null: the URDF's <limit velocity>",
    "max_acceleration": "rad/s^2, a number or one per joint (the moving test's limits)",
    "max_jerk": "rad/s^3, a number or one per joint: the limit of a policy's reference in a "
    "control loop; null: 7500 (Franka's published limit)",
    "max_torque": "N m, a number or one per joint; null: the URDF's <limit effort> (MuJoCo's "
    "motors)",
    "damping": "joint damping (N m s / rad), a number or one per joint",
    "armature": "rotor armature (kg m^2), a number or one per joint",
    "capsules": "collision volumes: auto (fitted to the URDF's <collision> geometry), none, or "
    "{link: [{a: [x,y,z], b: [x,y,z], radius: r}]} in the link frames",
    "forearm_link": "a link whose capsules the volume objective reads besides the end link's; "
    "null: none; auto: "
    "the link the third joint from the end moves (the Panda's link 5, the iiwa's link 5)",
    "base_links": "links fixed to the table (no table check); auto: the links before the first "
    "joint",
    "point_masses": "[{link, pos, mass, inertia: [ixx, iyy, izz]}]: bodies the URDF lacks (e.g. "
    "fingers)",
    "packages": "folders where package://NAME/... meshes are looked up (after the URDF's folders, "
    "ROS_PACKAGE_PATH)",
    "locked": "{joint: value}: joints off the chain to the end link held there (default 0)",
    "limits": "{joint: [lower, upper]}: limits of continuous joints (default [-pi, pi])",
    "balance_inertia": "true: inertias violating A + B >= C balanced with a warning; false: "
    "refused",
}


def shipped_robots() -> list[str]:
    """Names of the descriptions shipped in ``protorch/robots/`` (``<name>.yaml``)."""
    return sorted(p.stem for p in ROBOTS_DIR.glob("*.yaml"))


def _shipped(name: str) -> dict:
    data = shipped_yaml(name)
    if data is None:
        raise RobotError(
            f"robot.base={name!r} is not a shipped robot; shipped: {', '.join(shipped_robots())}"
        )
    return data


def robot_settings(spec=None) -> dict:
    """The full settings dict of ``spec`` (``None``: the Panda; a shipped name; a dict of
    ``robot.*`` settings, its non-null values over its ``base``'s): every key of
    :data:`DEFAULTS`."""
    if spec is None:
        spec = "panda"
    if isinstance(spec, str):
        spec = {"base": spec}
    if not isinstance(spec, dict):
        raise RobotError(
            f"robot must be a shipped name or a group of settings, got {type(spec).__name__}"
        )
    unknown = sorted(set(spec) - set(DEFAULTS))
    if unknown:
        raise RobotError(f"robot.{unknown[0]} is not a robot setting; known: {', '.join(DEFAULTS)}")
    base = spec.get("base")
    if base is not None and not isinstance(base, str):
        raise RobotError(f"robot.base={base!r} must be a shipped robot's name or null")
    out = dict(DEFAULTS)
    if base:
        shipped = _shipped(base)
        unknown = sorted(set(shipped) - set(DEFAULTS))
        if unknown:
            raise RobotError(f"protorch/robots/{base}.yaml: {unknown[0]!r} is not a robot setting")
        out.update(shipped)
    out.update({k: v for k, v in spec.items() if v is not None and v != "???"})
    for key in ("urdf", "mjcf"):
        if out[key] is not None and not isinstance(out[key], (str, Path)):
            raise RobotError(f"robot.{key}={out[key]!r} must be a file path")
    if out["urdf"] is None and out["mjcf"] is None:
        raise RobotError(
            "robot.urdf must be set (robot=custom needs robot.urdf, or robot.mjcf for an MJCF "
            "file; robot.end_link and robot.home are found where not given)"
        )
    if out["urdf"] is not None and out["mjcf"] is not None:
        raise RobotError(
            f"robot.urdf={out['urdf']} and robot.mjcf={out['mjcf']} are both set"
            + (f" (robot.base={base} gives the URDF)" if base else "")
            + ": give one"
        )
    for key in ("urdf", "mjcf"):
        if out[key] is not None:
            out[key] = str(Path(out[key]).expanduser().resolve())
    out["base"] = base
    return out


def _parse(text: str, where: str) -> ET.Element:
    try:
        return parse_urdf(text, where)
    except ValueError as exc:
        raise RobotError(str(exc)) from None


def check_inertials(robot: Robot) -> None:
    """Refuse, with one line naming the link, a robot whose moving links (the children of its
    joints) lack a mass and inertia: what the MuJoCo scene needs (before any work)."""
    root = _parse(robot.urdf_text, f"robot.urdf={robot.urdf}")
    for j in urdf_chain(root, robot.end_link):
        if j.get("type") == "fixed":
            continue
        link = j.find("child").get("link")
        inertial = robot.inertials.get(link)
        if inertial is None or not inertial.mass > 0:
            raise RobotError(
                f"robot.urdf={robot.urdf}: link {link!r} (moved by joint {j.get('name')!r}) has no "
                "<inertial> with a mass > 0; physics needs every moving link's mass and inertia: "
                "add "
                "them to the URDF or set settings.physics.run=never"
            )


def _end_link(root: ET.Element, value, where: str) -> tuple[str, bool]:
    """``(end link, found)``: the setting, or the one leaf reached through the most
    moving joints."""
    if value is not None:
        if not isinstance(value, str):
            raise RobotError(f"robot.end_link={value!r} must be a link's name")
        return value, False
    cands = end_link_candidates(root)
    if not cands:
        raise RobotError(f"{where} has no leaf link to end the chain at; give robot.end_link")
    top = [name for name, n in cands if n == cands[0][1]]
    if len(top) > 1:
        raise RobotError(
            f"robot.end_link is not set and {where} has {len(top)} leaf links reached through "
            f"{cands[0][1]} moving joints: {top}; give robot.end_link=LINK"
        )
    return top[0], True


def _mapping(value, key: str, what: str) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise RobotError(f"robot.{key}={value!r} must be {what}")
    return dict(value)


def load_robot(spec=None) -> Robot:
    """The :class:`~protorch.robots.Robot` of ``spec``: ``None`` (the Panda), a shipped name, a
    dict of ``robot.*`` settings (module docstring) or a ``Robot`` (returned as it is). Every
    bad input is a :class:`RobotError` of one line naming the setting, before any work."""
    if isinstance(spec, Robot):
        return spec
    cfg = robot_settings(spec)
    kind = "mjcf" if cfg["mjcf"] is not None else "urdf"
    path = Path(cfg[kind])
    where = f"robot.{kind}={path}"
    if not path.is_file():
        raise RobotError(f"{where}: no such file")
    stat = path.stat()
    try:
        key = json.dumps(cfg, sort_keys=True) + f"|{stat.st_mtime_ns}|{stat.st_size}"
    except TypeError:  # a setting JSON cannot hold: refused below, not cached
        key = None
    if key is not None and key in _LOADED:
        return _LOADED[key]
    found: dict = {}
    if kind == "mjcf":  # an MJCF file: read by MuJoCo, written once as a URDF (robots.mjcf)
        try:
            path, found["mjcf"] = mjcf_urdf(path, where)
        except (MjcfError, OSError) as exc:
            raise RobotError(str(exc).splitlines()[0]) from None
    robot = _load(cfg, path, where, found)
    if key is not None:
        _LOADED[key] = robot
        while len(_LOADED) > 16:
            _LOADED.pop(next(iter(_LOADED)))
    return robot


_LOADED: dict[str, Robot] = {}  # load_robot's results by settings and file (a Robot is frozen)


def _checked_settings(cfg: dict) -> tuple[list, dict, dict]:
    """``robot.packages``, ``robot.limits`` and ``robot.locked`` checked (and
    ``robot.balance_inertia``): one ``RobotError`` naming the setting."""
    packages = cfg["packages"] or []
    if isinstance(packages, (str, Path)) or not isinstance(packages, (list, tuple)):
        raise RobotError(f"robot.packages={packages!r} must be a list of folders")
    if not isinstance(cfg["balance_inertia"], bool):
        raise RobotError(f"robot.balance_inertia={cfg['balance_inertia']!r} must be true or false")
    limits = _mapping(cfg["limits"], "limits", "{joint: [lower, upper]}")
    for name, lim in limits.items():
        ok = (
            isinstance(lim, (list, tuple))
            and len(lim) == 2
            and all(
                isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)
                for v in lim
            )
        )
        if not ok or not lim[0] < lim[1]:
            raise RobotError(
                f"robot.limits.{name}={lim!r} must be [lower, upper] with lower < upper (rad)"
            )
    locked = _mapping(cfg["locked"], "locked", "{joint: value}")
    for name, v in locked.items():
        if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
            raise RobotError(
                f"robot.locked.{name}={v!r} must be a number (rad, or m for a sliding joint)"
            )
    return packages, limits, locked


def _load(cfg: dict, path: Path, where: str, found: dict) -> Robot:
    root = _parse(path.read_text(), where)
    end_link, auto_end = _end_link(root, cfg["end_link"], where)
    links = [link.get("name") for link in root.iter("link")]
    if end_link not in links:
        raise RobotError(
            f"robot.end_link={end_link!r} is not a link of {where}; its links are {links}"
        )
    if auto_end:
        found["end_link"] = end_link
    packages, limits, locked = _checked_settings(cfg)
    try:
        cleaned = clean_urdf(
            path,
            end_link,
            locked=locked,
            limits=limits,
            packages=packages,
            balance=cfg["balance_inertia"],
            where=where,
        )
    except (CleanError, FileNotFoundError, ValueError, ImportError) as exc:
        raise RobotError(str(exc).splitlines()[0]) from None
    report = {k: v for k, v in cleaned.report.items() if v}
    found.update(report)
    text = cleaned.text
    root = _parse(text, where)
    joints, moving, names = _chain(root, end_link, where)
    lower, upper, vel, eff = _urdf_limits(moving, where)
    n = len(names)
    velocity = _urdf_or_default(
        cfg["max_velocity"],
        vel,
        n,
        names,
        "max_velocity",
        DEFAULT_VELOCITY,
        MAX_PLAUSIBLE_VELOCITY,
        found,
        where,
    )
    torque = _urdf_or_default(
        cfg["max_torque"], eff, n, names, "max_torque", DEFAULT_EFFORT, math.inf, found, where
    )
    if _write_limits(root, moving, velocity, torque):  # a default or a setting: into the text
        text = ET.tostring(root, encoding="unicode")
    frame_names = [joints[0].find("parent").get("link")] + [
        j.find("child").get("link") for j in joints
    ]
    capsules = capsules_setting(cfg["capsules"], text, frame_names, where)
    home = cfg["home"]
    if home is None:
        home = _auto_home(text, end_link, capsules, found, where)
        cfg = {
            **cfg,
            "home": list(home),
        }  # a worker reloading robot.settings gets this home, unmeasured
    if not isinstance(home, (list, tuple)) or len(home) != n:
        raise RobotError(
            f"robot.home={home!r} must be {n} joint angles (rad), one per joint {names}"
        )
    home = tuple(_angle(v, i, names) for i, v in enumerate(home))
    for q, lo, hi, name in zip(home, lower, upper, names):
        if not lo <= q <= hi:
            raise RobotError(
                f"robot.home has {q} for joint {name!r}, outside its limits [{lo}, {hi}]"
            )
    first_moving = next(i for i, j in enumerate(joints) if j.get("type") != "fixed")
    base_links = cfg["base_links"]
    if base_links == "auto":
        base_links = frame_names[: first_moving + 1]
    if not isinstance(base_links, (list, tuple)) or any(b not in frame_names for b in base_links):
        raise RobotError(
            f"robot.base_links={base_links!r} must be auto or links of the chain {frame_names}"
        )
    forearm = cfg["forearm_link"]
    if (
        forearm == "auto"
    ):  # the forearm: what the third joint from the end moves (wrist joints after it)
        forearm = moving[-3].find("child").get("link")
        forearm = forearm if forearm in capsules else None
        found["forearm_link"] = forearm
    if forearm is not None and forearm not in frame_names:
        raise RobotError(f"robot.forearm_link={forearm!r} is not a link of the chain {frame_names}")
    name = cfg["name"] if cfg["name"] is not None else (root.get("name") or path.stem)
    _log_found(found, where)
    return Robot(
        name=str(name),
        urdf=path,
        end_link=end_link,
        joint_names=tuple(names),
        home=home,
        lower=tuple(lower),
        upper=tuple(upper),
        max_velocity=velocity,
        max_acceleration=joint_vector(cfg["max_acceleration"], n, "max_acceleration", names),
        max_jerk=joint_vector(
            DEFAULT_JERK if cfg["max_jerk"] is None else cfg["max_jerk"], n, "max_jerk", names
        ),
        max_torque=torque,
        damping=joint_vector(cfg["damping"], n, "damping", names, positive=False),
        armature=joint_vector(cfg["armature"], n, "armature", names, positive=False),
        capsules=capsules,
        base_links=tuple(base_links),
        forearm_link=forearm,
        inertials=urdf_inertials(root),
        point_masses=point_masses_setting(cfg["point_masses"], frame_names),
        settings=cfg,
        text=text,
        found=found,
    )


def _chain(root: ET.Element, end_link: str, where: str) -> tuple[list, list, list[str]]:
    """``(joints, moving joints, their names)`` of the chain to ``end_link``: revolute (or
    continuous) and fixed joints only, at least ``MIN_JOINTS`` moving."""
    joints = urdf_chain(root, end_link)
    moving = [j for j in joints if j.get("type") != "fixed"]
    kinds = sorted({j.get("type") for j in moving} - {"revolute"})
    if kinds:
        raise RobotError(
            f"{where}: the chain to robot.end_link={end_link!r} has {kinds[0]} joints; "
            "only revolute, continuous and fixed joints are supported"
        )
    names = [j.get("name") for j in moving]
    if len(names) < MIN_JOINTS:
        raise RobotError(
            f"robot.end_link={end_link!r}: the chain of {where} to it has {len(names)} joints "
            f"{names}; the arm experiment needs at least {MIN_JOINTS}"
        )
    return joints, moving, names


def _urdf_limits(moving: list, where: str) -> tuple[list, list, list, list]:
    """``(lower, upper, velocity, effort)`` of the chain's moving joints from their ``<limit>``
    (velocity and effort ``None`` where missing); a joint without lower and upper refused."""
    lower, upper, vel, eff = [], [], [], []
    for j in moving:
        lim = j.find("limit")
        get = (lambda k: None) if lim is None else lim.get
        if get("lower") is None or get("upper") is None:
            raise RobotError(f"{where}: joint {j.get('name')!r} has no <limit lower=... upper=...>")
        lo, hi = float(get("lower")), float(get("upper"))
        if not lo < hi:
            raise RobotError(
                f"{where}: joint {j.get('name')!r} has limits lower={lo} >= upper={hi}"
            )
        lower.append(lo)
        upper.append(hi)
        vel.append(float(get("velocity")) if get("velocity") is not None else None)
        eff.append(float(get("effort")) if get("effort") is not None else None)
    return lower, upper, vel, eff


def _write_limits(root: ET.Element, moving: list, velocity, torque) -> bool:
    """The resolved velocity and torque limits written into the chain's ``<limit>`` elements, so
    that every reader of the robot's URDF text (its kinematics' ``max_velocity``, the MuJoCo
    scene's motors) sees ``robot.max_velocity`` and ``robot.max_torque``; whether any changed."""
    changed = False
    for j, v, e in zip(moving, velocity, torque):
        lim = j.find("limit")
        for key, value in (("velocity", v), ("effort", e)):
            old = lim.get(key)
            if old is None or float(old) != float(value):
                lim.set(key, repr(float(value)))
                changed = True
    return changed


def _log_found(found: dict, where: str) -> None:
    """One line of what was found (end link, home, forearm link, locked joints), where any was."""
    parts = []
    if "end_link" in found:
        parts.append(f"end link {found['end_link']!r} (the leaf through the most moving joints)")
    if "home" in found:
        h = found["home"]
        parts.append(
            f"home {[round(v, 4) for v in h['pose']]} (hand down at {h['target']}, IK residual "
            f"{h['residual']:.1e} m, from {h['seed']})"
        )
    if found.get("forearm_link"):
        parts.append(f"forearm link {found['forearm_link']!r}")
    if found.get("locked"):
        parts.append(f"locked {found['locked']}")
    if parts:
        log.info("%s: found %s", where, "; ".join(parts))


def _auto_home(text: str, end_link: str, capsules, found: dict, where: str) -> list[float]:
    """The hand-down home (:func:`protorch.robots.layout.hand_down_layout`, the hand's capsules
    kept as high above the table as the Panda's), its report in ``found``."""

    kin = ArmKinematics(text, end_link=end_link)
    try:
        layout = hand_down_layout(kin, f"the arm of {where}", hand_drop(kin, capsules))
    except ValueError as exc:
        raise RobotError(str(exc)) from None
    found["home"] = {
        "pose": layout["home"],
        "target": layout["home_target"],
        "residual": layout["home_residual"],
        "seed": layout["home_seed"],
    }
    found["layout"] = layout
    return layout["home"]


def _angle(v, i: int, names) -> float:
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(float(v)):
        raise RobotError(f"robot.home has {v!r} for joint {names[i]!r}: it must be an angle (rad)")
    return float(v)


def _urdf_or_default(
    value, urdf: list, n: int, names, key: str, default: float, most: float, found: dict, where: str
) -> tuple[float, ...]:
    """A limit from the setting ``robot.<key>`` or, where it is null, the URDF's; where the URDF's
    is missing, not positive or above ``most``: ``default``, with a warning naming the joints."""
    if value is not None:
        return joint_vector(value, n, key, names)
    bad = [name for v, name in zip(urdf, names) if v is None or not 0 < v <= most]
    if bad:
        log.warning(
            "%s: joints %s have no plausible <limit %s> (missing, <= 0 or > %g): %g used (set "
            "robot.%s)",
            where,
            bad,
            "velocity" if key == "max_velocity" else "effort",
            most,
            default,
            key,
        )
        found[f"{key}_default"] = {"joints": bad, "value": default}
    return tuple(default if name in bad else float(v) for v, name in zip(urdf, names))
