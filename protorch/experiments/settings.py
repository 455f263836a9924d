"""Typed settings: dataclass schemas of the experiments' settings, checked before any work.

Each schema field carries its one-line meaning (``help``, the source of ``--help`` text) and its
allowed range (``ge`` / ``gt`` / ``choices``). :func:`validate` checks a plain dict against a
schema and raises :class:`SettingsError` with ONE line naming the full key, the value and what is
allowed, e.g. ``settings.loop.num_envs='abc' must be an int >= 1``.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass
from typing import Any

from ..errors import ProtorchError
from ..loop.settings import LOOP_GROUP, LoopSettings

__all__ = [
    "SettingsError",
    "setting",
    "validate",
    "describe",
    "OPTIMIZER_SCHEMAS",
    "GP",
    "Loop",
    "Test",
    "ProMPSettings",
]


class SettingsError(ProtorchError, ValueError):
    """A setting of the wrong type or out of range; its message is one line."""


def setting(
    default=dataclasses.MISSING, help: str = "", *, ge=None, gt=None, le=None, choices=None
) -> Any:
    """A schema field with its meaning and allowed range (``Any``: a ``dataclasses.field`` that
    stands for a value of the field's annotated type)."""
    meta = {"help": help, "ge": ge, "gt": gt, "le": le, "choices": choices}
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=lambda d=default: type(d)(d), metadata=meta)
    if dataclasses.is_dataclass(default):
        return dataclasses.field(
            default_factory=lambda d=default: dataclasses.replace(d), metadata=meta
        )
    return dataclasses.field(default=default, metadata=meta)


def _range_text(meta: dict) -> str:
    parts = [
        f"{op} {meta[k]}"
        for k, op in (("ge", ">="), ("gt", ">"), ("le", "<="))
        if meta.get(k) is not None
    ]
    return " and ".join(parts)


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check_scalar(tp, value, meta: dict) -> str | None:
    """What ``value`` must be, or ``None`` when it is fine."""
    rng = _range_text(meta)
    if tp is bool:
        return None if isinstance(value, bool) else "true or false"
    if tp is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
        what = "an int" + (f" {rng}" if rng else "")
    elif tp is float:
        ok = _number(value) and not math.isnan(float(value))
        what = "a number" + (f" {rng}" if rng else "")
    elif tp is str:
        choices = meta.get("choices")
        ok = isinstance(value, str) and (choices is None or value in choices)
        return None if ok else ("one of " + ", ".join(map(str, choices)) if choices else "a string")
    else:
        return None
    if ok:
        checks = (
            ("ge", lambda a, b: a >= b),
            ("gt", lambda a, b: a > b),
            ("le", lambda a, b: a <= b),
        )
        ok = all(meta.get(k) is None or f(value, meta[k]) for k, f in checks)
    return None if ok else what


def _check(tp, value, meta: dict, key: str):
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is typing.Union or origin is types.UnionType:
        if value is None and type(None) in args:
            return value
        inner = [a for a in args if a is not type(None)]
        errors = []
        for tp_i in inner:
            try:
                return _check(tp_i, value, meta, key)
            except SettingsError as exc:
                errors.append(str(exc).partition(" must be ")[2])
        what = " or ".join(errors + (["null"] if type(None) in args else []))
        raise SettingsError(f"{key}={value!r} must be {what}")
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise SettingsError(
                f"{key}={value!r} must be a group of settings ("
                f"{', '.join(f.name for f in dataclasses.fields(tp))})"
            )
        return validate(tp, value, key)
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise SettingsError(f"{key}={value!r} must be a list")
        for i, v in enumerate(value):
            _check(args[0], v, meta, f"{key}[{i}]")
        return value
    if origin is dict or tp is typing.Any:
        return value
    what = _check_scalar(tp, value, meta)
    if what is not None:
        raise SettingsError(f"{key}={value!r} must be {what}")
    return value


def validate(schema: type, data: dict | None, where: str) -> dict:
    """``data`` checked against the dataclass ``schema``: unknown keys, types and ranges; every
    problem raises :class:`SettingsError` naming ``where.key``. Returns ``data`` (values
    unchanged)."""
    data = dict(data or {})
    hints = typing.get_type_hints(schema)
    fields = {f.name: f for f in dataclasses.fields(schema)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise SettingsError(
            f"{where}.{unknown[0]} is not a setting of {where}; known: {', '.join(sorted(fields))}"
        )
    for name, value in data.items():
        _check(hints[name], value, dict(fields[name].metadata), f"{where}.{name}")
    return data


def describe(schema: type, where: str) -> dict[str, str]:
    """``{"where.key": one-line meaning}`` of every field, nested groups included."""
    out = {}
    hints = typing.get_type_hints(schema)
    for f in dataclasses.fields(schema):
        key, tp = f"{where}.{f.name}", hints[f.name]
        out[key] = f.metadata.get("help", "")
        if dataclasses.is_dataclass(tp):
            out.update(describe(tp, key))
    return out


# ----------------------------------------------------------------------------- shared groups
@dataclass
class _Shared:
    name: str = setting("pro", "the optimiser (a key of protorch.optim.OPTIMIZERS)")
    num_samples: int = setting(100, "weight samples per iteration", ge=2)
    max_iter: int = setting(200, "iteration limit", ge=1)
    tol: float = setting(
        1e-3,
        "converged: every objective's mean sample cost within tol over `window` iterations; 0 = "
        "never",
        ge=0,
    )
    window: int = setting(5, "iterations the convergence rule looks back over", ge=1)
    convergence: str = setting(
        "mean",
        "stop rule: mean (each objective's mean sample cost) | authors (every "
        "sample, plus the task's thresholds; point particle)",
        choices=("mean", "authors"),
    )


@dataclass
class _RewardWeighted(_Shared):
    beta: float = setting(10.0, "reward exp(-beta * cost); larger = greedier", gt=0)


@dataclass
class ProSettings(_RewardWeighted):
    relevance_samples: int = setting(100, "samples of the relevance estimate", ge=2)
    relevance_var: float = setting(1e-5, "variance of the relevance samples' perturbation", gt=0)
    relevance_every: int = setting(1, "recompute the relevance every k iterations", ge=1)
    noise_floor: typing.Optional[float] = setting(
        None, "|rho| below noise_floor / sqrt(samples) counts as 0; null = as written", ge=0
    )


@dataclass
class RwrSettings(_RewardWeighted):
    center: str = setting(
        "new", "variance about the new mean (textbook RWR) or the old one", choices=("new", "old")
    )


@dataclass
class RwpoSettings(_RewardWeighted):
    relevance_iters: int = setting(50, "iterations of the relevance search", ge=1)
    theta_samples: int = setting(200, "relevance-parameter samples per relevance iteration", ge=2)
    trajectory_samples: int = setting(50, "trajectory samples per relevance candidate", ge=1)
    relevance_beta: float = setting(10.0, "reward temperature of the relevance search", gt=0)
    relevance_every: int = setting(0, "relearn the relevance every k iterations; 0 = once", ge=0)


@dataclass
class CemSettings(_Shared):
    elite_frac: float = setting(0.1, "fraction of the samples refitted", gt=0, le=1)
    smoothing: float = setting(1.0, "step towards the elites' Gaussian", gt=0, le=1)
    extra_var: float = setting(0.0, "variance added after each refit (the noisy CEM)", ge=0)


@dataclass
class CmaesSettings(_Shared):
    pycma_stop: bool = setting(True, "also stop where pycma's termination criteria say so")
    cma_options: typing.Optional[dict] = setting(None, "extra pycma options")


OPTIMIZER_SCHEMAS: dict[str, type] = {
    "pro": ProSettings,
    "rwr": RwrSettings,
    "rwpo": RwpoSettings,
    "cem": CemSettings,
    "cmaes": CmaesSettings,
}


@dataclass
class GP:
    backend: str = setting("torch", "the environment map (a key of protorch.gp.BACKENDS)")
    alpha: float = setting(1.0, "kernel exp(-alpha ||e - e'||^2)", gt=0)
    var_floor: float = setting(
        0.0, "lower bound on a data-set entry's variance = its GP noise", ge=0
    )
    nearest_k: typing.Optional[int] = setting(
        None, "condition on the k nearest known environments; null = all", ge=1
    )
    neighbours: typing.Optional[int] = setting(
        None, "gp=sparse: environments per solve where nearest_k is null (null: 32)", ge=1
    )


@dataclass
class ProMPSettings:
    num_basis: int = setting(10, "Gaussian basis functions per degree of freedom", ge=2)
    num_steps: int = setting(100, "time steps of a trajectory", ge=2)


def _section(source: type, names: tuple[str, ...], name: str) -> type:
    """A schema dataclass holding ``names`` of the dataclass ``source``: their types, defaults,
    meanings and ranges as ``source`` defines them (one definition, read by the app too)."""
    hints = typing.get_type_hints(source)
    fields = {f.name: f for f in dataclasses.fields(source)}
    return dataclasses.make_dataclass(
        name,
        [
            (n, hints[n], dataclasses.field(default=fields[n].default, metadata=fields[n].metadata))
            for n in names
        ],
        namespace={"__module__": __name__, "__doc__": f"The {source.__name__} fields {names}."},
    )


# the loop group: LoopSettings' fields that an experiment's loop group sets (LOOP_GROUP)
Loop = _section(LoopSettings, LOOP_GROUP, "Loop")


@dataclass
class Test:
    num_envs: int = setting(200, "held-out random environments", ge=1)
    seed: int = setting(2_000_003, "their seed (never a training seed)", ge=0)


# ----------------------------------------------------------------------------- experiments
@dataclass
class ParticleLoop(Loop):  # type: ignore[misc, valid-type]
    stop_when_solved: bool = setting(False, "stop a problem once its mean passes with margins")


@dataclass
class ParticleDynamic:
    seed: int = setting(3_000_017, "seed of the moving episodes (never a training seed)", ge=0)
    episodes: int = setting(100, "moving-environment episodes", ge=0)
    duration: float = setting(2.0, "seconds of motion", gt=0)
    hold: float = setting(0.5, "seconds held at the end", ge=0)
    dt: float = setting(0.01, "control step (s)", gt=0)
    kp: float = setting(1000.0, "PD stiffness", gt=0)
    kd: float = setting(30.0, "PD damping", ge=0)
    step_std: typing.Any = setting(
        None, "random-walk step of the moving hole and goal (a number or one per entry)"
    )
    start: str = setting("env", "where the particle starts")
    goal_tol: float = setting(0.2, "distance to the goal that counts as reached", gt=0)


@dataclass
class ParticlePaperDynamic:
    seed: int = setting(3_000_029, "seed of the authors' moving test (never a training seed)", ge=0)
    episodes: int = setting(
        100, "episodes of the authors' moving test (start fixed; wall, hole, goal moving)", ge=0
    )
    duration: float = setting(2.0, "seconds of motion", gt=0)
    hold: float = setting(0.5, "seconds held at the end", ge=0)
    dt: float = setting(0.01, "control step (s)", gt=0)
    kp: float = setting(1000.0, "PD stiffness", gt=0)
    kd: float = setting(30.0, "PD damping", ge=0)
    start: str = setting("env", "where the particle starts")
    goal_tol: float = setting(0.2, "distance to the goal that counts as reached", gt=0)


@dataclass
class PointParticleSettings:
    promp: ProMPSettings = setting(ProMPSettings(), "the ProMP's basis")
    loop: ParticleLoop = setting(ParticleLoop(), "the self-improvement loop")
    test: Test = setting(Test(), "the held-out test")
    dynamic: ParticleDynamic = setting(ParticleDynamic(), "the moving-environment episodes")
    dynamic_paper: ParticlePaperDynamic = setting(
        ParticlePaperDynamic(), "the authors' moving test (main3.py)"
    )
    baselines: list[str] = setting(
        ["demos_only", "rwr"], "baselines run alongside", choices=("demos_only", "rwr")
    )
    progress: bool = setting(True, "show progress bars")


@dataclass
class ArmLoop(Loop):  # type: ignore[misc, valid-type]
    labels: bool = setting(True, "label solutions by homotopy class; false: the paper's single map")
    each_label: bool = setting(True, "optimise every class's prediction for each environment")


@dataclass
class ArmDynamic:
    seed: int = setting(3_000_017, "seed of the moving episodes (never a training seed)", ge=0)
    episodes: int = setting(100, "moving episodes", ge=0)
    duration: float = setting(3.0, "seconds of motion", gt=0)
    hold: float = setting(1.0, "seconds held at the end", ge=0)
    dt: float = setting(0.02, "control step (s); the map is queried every step", gt=0)
    kp: float = setting(10.0, "joint-space stiffness", gt=0)
    moves: list[int] = setting([1, 2], "the can or the target is moved this many times per episode")
    move_window: list[float] = setting(
        [0.1, 0.6], "fraction of the motion in which the moves happen"
    )
    place_clearance: float = setting(0.05, "clearance of a moved object to the arm (m)", ge=0)
    switch_margin: float = setting(0.02, "cost margin before the arm switches class", ge=0)
    check: bool = setting(
        True,
        "pass over a class whose plan for the rest of the motion touches the can "
        "(false: the summed objectives alone choose)",
    )
    switch_clearance: float = setting(
        0.01,
        "the check's hysteresis (m): another class than the tracked one counts "
        "as clear only with this much more than the margin (0: none)",
        ge=0,
    )


@dataclass
class ArmPhysics:
    run: str = setting(
        "auto",
        "execute the map's motions in MuJoCo: auto (where mujoco is installed; else one line "
        "naming the extra) | always (refuse to start without it) | never",
        choices=("auto", "always", "never"),
    )
    timestep: float = setting(
        0.002, "MuJoCo's physics step (s); the control step dynamic.dt is a whole multiple", gt=0
    )
    kp: float = setting(
        400.0, "computed-torque stiffness (1/s^2); kp h^2 + 2 kd h < 4 at the timestep h", gt=0
    )
    kd: float = setting(40.0, "computed-torque damping (1/s)", ge=0)
    mass_scale: float = setting(
        1.0, "the controller model's link masses and inertias / the simulated arm's", gt=0
    )
    feasible: bool = setting(
        True,
        "torque-feasible reference: its acceleration scaled down where the command would "
        "pass feasible_scale of the torque limits (false: tracked as planned)",
    )
    feasible_scale: float = setting(
        0.9, "the fraction of the torque limits the feasible reference keeps within", gt=0, le=1
    )
    render: bool = setting(
        True, "render a held-out reach and a switching episode (GIF + frames; needs EGL or OSMesa)"
    )


@dataclass
class ArmReachSettings:
    promp: ProMPSettings = setting(ProMPSettings(), "the ProMP's basis")
    loop: ArmLoop = setting(ArmLoop(), "the self-improvement loop")
    test: Test = setting(Test(), "the held-out test")
    dynamic: ArmDynamic = setting(ArmDynamic(), "the moving episodes")
    physics: ArmPhysics = setting(ArmPhysics(), "the held-out and moving tests executed in MuJoCo")
    baselines: list[str] = setting(
        ["labels_off", "labels_off_loop"],
        "baselines run alongside",
        choices=("labels_off", "labels_off_loop"),
    )
    progress: bool = setting(True, "show progress bars")
    threads: typing.Optional[int] = setting(
        None, "torch threads inside the experiment; null = the top-level threads setting", ge=1
    )


@dataclass
class SelfImproveSettings:
    promp: ProMPSettings = setting(ProMPSettings(), "the ProMP's basis")
    loop: Loop = setting(Loop(), "the self-improvement loop")  # type: ignore[valid-type]
    test: Test = setting(Test(), "the held-out test")
    baselines: list[str] = setting(
        ["demos_only"], "baselines run alongside", choices=("demos_only",)
    )
    progress: bool = setting(False, "show progress bars")


# each experiment's class (protorch.experiments.registry) names its settings.* schema


@dataclass
class RecordingsSettings:
    trim: typing.Any = setting(
        0.05, "idle ends: speed below this fraction of the recording's peak is cut (false: off)"
    )
    align: bool = setting(
        True, "DTW time alignment of the recordings of one environment (and side)"
    )
    samples: int = setting(200, "points per demonstration, equally spaced in time", ge=2)
    min_duration: float = setting(
        0.5, "s a recording (and its motion after trimming) lasts at least", gt=0
    )
    group_tol: typing.Any = setting(
        "auto",
        "recordings whose environments are closer are one environment "
        "(auto: derived from the data)",
    )
    window: float = setting(0.05, "s of smoothing before the speed is measured", gt=0)


@dataclass
class PointParticleTaskSettings:
    objectives: str = setting("clearance", "the middle objective", choices=("clearance", "hole"))
    fixed_start: typing.Optional[list[float]] = setting(
        None, "a fixed start point instead of a random one"
    )
    infinite_wall: bool = setting(True, "the wall continues beyond y = 0 and y = 10")
    demos: str = setting(
        "synthetic", "synthetic, or a folder of trajK.out / envK.out or of *.csv recordings"
    )
    recordings: RecordingsSettings = setting(
        RecordingsSettings(), "a *.csv folder's cleaning (docs/recordings.md)"
    )
    demo_envs: int = setting(30, "synthetic only: demonstrated environments", ge=1)
    demos_per_env: int = setting(3, "synthetic only: demonstrations per environment", ge=2)


@dataclass
class ArmReachTaskSettings:
    demos: str = setting(
        "synthetic",
        "synthetic, or a folder of trajK.out (one angle per joint per row) / envK.out, "
        "or of *.csv recordings",
    )
    recordings: RecordingsSettings = setting(
        RecordingsSettings(), "a *.csv folder's cleaning (docs/recordings.md)"
    )
    demo_envs: int = setting(20, "synthetic only: demonstrated environments", ge=1)
    demos_per_env: int = setting(3, "synthetic only: demonstrations per environment", ge=2)
    priors: int = setting(2004, "straight-path prior ProMPs on a regular grid", ge=0)
    prior_grid: str = setting(
        "rectangles",
        "the priors' grid spans the sampler's rectangles or the table",
        choices=("rectangles", "table"),
    )
    region: str = setting(
        "rectangles", "where the loop's pool and the tests draw", choices=("rectangles", "table")
    )
    reach: typing.Optional[list[float]] = setting(
        None, "(r_min, r_max) the hand-down arm reaches on the table"
    )
    cost_steps: typing.Optional[int] = setting(
        25, "time steps the objectives are evaluated on; null = all", ge=2
    )
    margin: typing.Optional[float] = setting(
        None,
        "clearance of the arm to the can's surface, for success; "
        "null = 0.02 for the skeleton, 0.01 for the volumes",
        ge=0,
    )
    goal_tol: float = setting(0.02, "success radius at the target (m)", gt=0)
    start_tol: float = setting(0.02, "success radius at the start (m)", gt=0)
    can_radius: typing.Any = setting(
        "auto", "the can's radius (m); auto: the Panda's 0.0375, scaled to a custom arm"
    )
    can_height: typing.Any = setting(
        "auto", "the can's height (m); auto: the Panda's 0.23, scaled to a custom arm"
    )
    clearance: float = setting(
        0.2, "the 0.2 of the can objective max(-min_t ||p - can||, -0.2)", gt=0
    )
    can_box: typing.Any = setting(
        "auto",
        "where the can is drawn: [[x_min, x_max], [y_min, y_max]] (m); auto: the "
        "Panda's [[0.50, 0.62], [-0.12, 0.12]], placed on a custom arm's reach",
    )
    goal_box: typing.Any = setting(
        "auto", "where the target is drawn; within the arm's reach (auto: as can_box)"
    )
    table: typing.Any = setting(
        "auto", "the table top; an environment off it is refused (auto: as can_box)"
    )
    deviation: str = setting(
        "segment",
        "d of the objectives: distance to the segment s -> g, or to tau_direct(t)",
        choices=("segment", "time"),
    )
    collision: str = setting(
        "volume",
        "the arm in planning and the success check: the robot's link capsules (as "
        "MuJoCo collides them), or segments between frame origins",
        choices=("skeleton", "volume"),
    )
    can_objective: str = setting(
        "auto",
        "the can objective's distance: the end effector's (the paper's), the "
        "capsules rigid with the end link and the forearm's, the arm's skeleton, or auto (volume "
        "with collision=volume)",
        choices=("auto", "ee", "volume", "skeleton"),
    )
    prior_clear: typing.Any = setting(
        "auto",
        "keep only the priors whose straight path succeeds under "
        "collision (true, false, auto: with collision=volume)",
    )
    prior_detours: typing.Any = setting(
        "auto",
        "distances (m) beside the can of the detour priors on both sides; "
        "auto: [0.18, 0.24] with collision=volume, [] with the skeleton",
    )
    plan_margin: typing.Optional[float] = setting(
        None,
        "the loop's margin: it accepts a solution only this far "
        "from the can (the tests keep margin); null: margin",
        ge=0,
    )


# each experiment's class (protorch.experiments.registry) names its task.* schema
