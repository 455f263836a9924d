"""What protorch found or defaulted for a robot, as the lines of a run's end-of-run summary:
:func:`robot_found_lines` reads ``metrics["robot"]["found"]`` (:meth:`Robot.summary
<protorch.robots.Robot.summary>`) and writes one line per finding: the end link, the home (pose,
inverse-kinematics residual and seed), the workspace, the forearm link, locked joints, continuous
joints' limits, balanced or replaced inertias, meshes read and converted, ignored tags, defaulted
velocity and torque limits, and the MJCF file a description was converted from."""

from __future__ import annotations

__all__ = ["robot_found_lines", "found_lines"]


def _nums(values, digits: int = 3) -> str:
    return "[" + ", ".join(f"{float(v):.{digits}f}" for v in values) + "]"


def _box(box) -> str:
    (x0, x1), (y0, y1) = box
    return f"x {x0:g}..{x1:g}, y {y0:g}..{y1:g}"


def _workspace(layout: dict) -> str:
    return (
        f"workspace (auto, reach x {layout['reach'][0]:g}..{layout['reach'][1]:g} m at height "
        f"{layout['height']:g} m): can {_box(layout['can_box'])}, target "
        f"{_box(layout['goal_box'])}, table {_box(layout['table'])}, can radius "
        f"{layout['can_radius']:g} m, height {layout['can_height']:g} m"
    )


def _mapping(values: dict) -> str:
    return ", ".join(
        f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in values.items()
    )


def found_lines(found: dict) -> list[str]:
    """One line per finding of ``found`` (:attr:`Robot.found <protorch.robots.Robot.found>`);
    none where nothing was found or defaulted."""
    out = []
    if found.get("mjcf"):
        m = found["mjcf"]
        out.append(
            f"converted from MJCF {m['file']}: {m['bodies']} bodies, {m['geoms']} geoms"
            + (
                f", joint velocities {m['velocity']:g} rad/s (MJCF has none)"
                if "velocity" in m
                else ""
            )
            + (f", ignored {_mapping(m['ignored'])}" if m.get("ignored") else "")
        )
    if found.get("end_link"):
        out.append(
            f"end link {found['end_link']} (the leaf reached through the most moving joints)"
        )
    if found.get("home"):
        h = found["home"]
        out.append(
            f"home {_nums(h['pose'])} rad: hand down at {_nums(h['target'], 4)} m, IK residual "
            f"{h['residual']:.1e} m, seed: {h['seed']}"
        )
    if found.get("layout"):
        out.append(_workspace(found["layout"]))
    if found.get("forearm_link"):
        out.append(f"forearm link {found['forearm_link']} (moved by the third joint from the end)")
    if found.get("locked"):
        out.append(f"locked off-chain joints: {_mapping(found['locked'])}")
    if found.get("continuous"):
        lims = {k: _nums(v) for k, v in found["continuous"].items()}
        out.append(f"continuous joints limited: {_mapping(lims)}")
    if found.get("balanced"):
        out.append(f"inertias balanced (A + B >= C): {', '.join(found['balanced'])}")
    if found.get("implausible"):
        out.append(
            f"implausible inertias replaced by the geometry's: {', '.join(found['implausible'])}"
        )
    if found.get("meshes"):
        out.append(
            f"meshes: {found['meshes']} read, {len(found.get('converted') or [])} converted for "
            "MuJoCo"
        )
    if found.get("ignored"):
        tags = ", ".join(f"{k} x{v}" for k, v in sorted(found["ignored"].items()))
        out.append(f"ignored tags: {tags}")
    for key, what, unit in (
        ("max_velocity_default", "velocity", "rad/s"),
        ("max_torque_default", "torque", "N m"),
    ):
        if found.get(key):
            d = found[key]
            out.append(
                f"{what} limit defaulted to {d['value']:g} {unit} (none plausible in the file): "
                f"{', '.join(d['joints'])}"
            )
    return out


def robot_found_lines(metrics: dict) -> list[str]:
    """The summary's robot section: ``"  robot NAME: found ..."`` then one indented line per
    finding of ``metrics["robot"]["found"]`` (:func:`found_lines`); ``[]`` for a run without a
    robot or where nothing was found or defaulted (the shipped robots)."""
    robot = metrics.get("robot") if isinstance(metrics, dict) else None
    if not isinstance(robot, dict) or not robot.get("found"):
        return []
    lines = found_lines(robot["found"])
    if not lines:
        return []
    return [f"  robot {robot.get('name', '?')}: found or defaulted"] + [f"    {s}" for s in lines]
