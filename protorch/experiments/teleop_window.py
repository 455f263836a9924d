"""Assisted teleoperation in a changing scene: the beam through a window whose wall moves.

1. **Demonstrations**: careful trials at a few static walls, both ways of rolling the beam up
   (:class:`~protorch.tasks.TeleopWindowTask`), labelled by class.
2. **The map** from wall poses to ProMPs over the 7-D pose: the self-improvement loop
   (:func:`protorch.loop.self_improve`, PRO by default, the classes kept apart and each learned
   at every wall), and a second map of the solutions' log-variance
   (:func:`~protorch.control.teleop_guide.variance_map`).
3. **Trials**: a population of simulated operators (``teleop.operator``: the shipped ``varied`` or
   ``screen``, or a plug-in ``PATH.py:CLASS`` / ``module.CLASS``), each with a wall schedule drawn
   from ``teleop.wall_seed``, in each condition: no guide, the guide fixed at the first wall pose,
   the adaptive guide (:class:`~protorch.control.teleop_guide.MixtureGuide`), the same operators
   and walls in every condition (:func:`~protorch.tasks.teleop_trials.run_trials`).
4. **Figure** ``teleop_trials.png``: the trials seen from above, one panel per condition.
5. **Freedom**: the adaptive guide of maps built by the same loop with CEM and CMA-ES (the same
   demonstrations, walls and budget) on the same trials: their compliance beside PRO's.

The loop optimiser's map and variance map are written to ``teleop_map.safetensors`` and
``teleop_var_map.safetensors`` (:func:`protorch.gp.load_env_map`), for ``python -m protorch.view
teleop RUN``.

Metrics: ``teleop.<condition>.{success_rate, collision_rate, time, effort, freedom}``;
``freedom.<optimiser>.{freedom, freedom_window, success_rate}``; ``map.*``.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import torch

from ..checks import check_int, check_keys
from ..control.teleop_guide import GUIDE_DEFAULTS, MixtureGuide, variance_map
from ..figures.teleop import teleop_figure
from ..gp import make_env_map
from ..loop import LoopSettings, OptimizerSpec, demonstration_dataset, self_improve
from ..optim import OPTIMIZERS
from ..primitives.promp import ProMP
from ..tasks.teleop_operators import careful_demonstrations, load_operator, probe_operator
from ..tasks.teleop_trials import CONDITIONS, SCHEDULE_DEFAULTS, draw_schedules, run_trials
from ..tasks.teleop_window import TeleopWindowTask
from ..threads import torch_threads
from .settings import SettingsError

__all__ = ["run", "build_map", "TELEOP_DEFAULTS", "MAP_FILE", "VAR_MAP_FILE"]

MAP_FILE, VAR_MAP_FILE = (
    "teleop_map.safetensors",
    "teleop_var_map.safetensors",
)  # the loop optimiser's maps

TELEOP_DEFAULTS = dict(
    operator="varied",
    operators=40,
    conditions=list(CONDITIONS),
    wall_seed=0,
    dt=0.02,
    time_limit=10.0,
    wall={},
)
_LOOP_DEFAULTS = dict(num_envs=24, batch_size=8, eval_dtype="float32")
_PEER_KEYS = (
    "num_samples",
    "max_iter",
    "tol",
    "window",
)  # what the freedom peers share with the loop's optimiser
_DEMO_KEYS = {"envs", "per_env"}
_GP_KEYS = {"backend", "alpha", "var_floor", "nearest_k"}
_DEMO_SEED = 101
_TEST_SEED = 2_000_003


def _refuse(msg: str):
    raise SettingsError(msg)


def _settings(task, demos, loop, gp, guide, teleop, freedom_optimizers):
    """Every setting checked (one line naming the bad one, before any work)."""
    for cfg, keys, where in (
        (demos, _DEMO_KEYS, "demos"),
        (loop, set(_LOOP_DEFAULTS), "loop"),
        (gp, _GP_KEYS, "gp"),
        (guide, set(GUIDE_DEFAULTS), "guide"),
        (teleop, set(TELEOP_DEFAULTS), "teleop"),
    ):
        try:
            check_keys(cfg, keys, where)
        except ValueError as exc:
            _refuse(str(exc))
    try:
        beam = TeleopWindowTask(
            **{k: tuple(v) if isinstance(v, list) else v for k, v in task.items()}
        )
        tele = {**TELEOP_DEFAULTS, **teleop}
        bad = [c for c in tele["conditions"] if c not in CONDITIONS]
        if bad or not tele["conditions"]:
            _refuse(
                "settings.teleop.conditions: unknown condition "
                f"{bad[0] if bad else '(none given)'!r}; "
                f"choose from {', '.join(CONDITIONS)}"
            )
        for key in ("operators", "wall_seed"):
            tele[key] = check_int(tele[key], f"teleop.{key}", 1 if key == "operators" else 0)
        for key in ("dt", "time_limit"):
            if not (math.isfinite(float(tele[key])) and float(tele[key]) > 0):
                _refuse(f"settings.teleop.{key} must be > 0, got {tele[key]}")
        draw_schedules(beam, 1, 0, **dict(tele["wall"]))  # the wall settings checked
        cls = load_operator(tele["operator"])
        start, end = beam.endpoint_poses()
        probe_operator(cls, beam, start, end, draw_schedules(beam, 1, 0).env0[0])
        for name in freedom_optimizers:
            if name not in OPTIMIZERS:
                _refuse(
                    f"settings.freedom_optimizers: {name!r} is no optimiser ("
                    f"{', '.join(sorted(OPTIMIZERS))})"
                )
        guide_cfg = {**GUIDE_DEFAULTS, **guide}
        for key, v in guide_cfg.items():
            if not (math.isfinite(float(v)) and float(v) >= 0):
                _refuse(f"settings.guide.{key} must be finite and >= 0, got {v}")
    except SettingsError:
        raise
    except ValueError as exc:
        raise SettingsError(" ".join(str(exc).split())) from None
    return beam, tele, cls, guide_cfg


def build_map(
    task,
    promp,
    demos,
    envs,
    labels,
    *,
    optimizer: str,
    optimizer_kwargs: dict,
    gp: dict,
    loop: dict,
    seed: int,
):
    """The self-improvement loop's map (``optimizer`` a registry name), its variance map and the
    loop's result."""
    gp_cfg = {"backend": "torch", "alpha": 3.0, **gp}
    backend, var_floor = gp_cfg.pop("backend"), float(gp_cfg.pop("var_floor", 0.0) or 1e-6)
    gp_cfg = {k: v for k, v in gp_cfg.items() if v is not None}
    factory = lambda: make_env_map(backend, **gp_cfg)  # noqa: E731
    lc = {**_LOOP_DEFAULTS, **loop}
    ds = demonstration_dataset(
        promp, demos, envs, labels=labels, var_floor=var_floor, task_name=task.name
    )
    settings = LoopSettings(
        num_envs=int(lc["num_envs"]),
        batch_size=int(lc["batch_size"]),
        add_only="success",
        each_label=True,
        seed=seed,
        var_floor=var_floor,
        eval_dtype=lc["eval_dtype"],
        refill=False,
        threads=1,
    )
    spec = OptimizerSpec(OPTIMIZERS[optimizer], optimizer_kwargs)
    res = self_improve(task, promp, ds, spec, factory, settings, labeler=task.label)
    return res.env_map, variance_map(factory, res.env_map), res


def _condition_metrics(r: dict, window: torch.Tensor | None = None) -> dict:
    return {
        "success_rate": float(r["success"].double().mean()),
        "collision_rate": float(r["collided"].double().mean()),
        "time": float(r["time"].median()),
        "effort": float(r["effort"].mean()),
        "freedom": float(r["freedom"].mean()),
        "trials": int(r["success"].numel()),
    }


def run(
    out_dir: Path,
    *,
    seed: int = 0,
    device="cpu",
    dtype=torch.float64,
    plot: bool = True,
    optimizer: dict,
    task: dict | None = None,
    gp: dict | None = None,
    demos: dict | None = None,
    promp: dict | None = None,
    loop: dict | None = None,
    guide: dict | None = None,
    teleop: dict | None = None,
    freedom_optimizers=("cem", "cmaes"),
    num_threads: int | None = 1,
    progress: bool = False,
) -> dict:
    """Run the experiment into ``out_dir`` (module docstring); every setting is checked first.

    ``optimizer``: the optimizer group (``{"name": "pro", "beta": ...}``) of the loop; ``demos``:
    ``envs`` walls x ``per_env`` demonstrations; ``promp``: ``num_basis``, ``num_steps``;
    ``loop``: ``num_envs``, ``batch_size``, ``num_samples``, ``max_iter``, ``eval_dtype``;
    ``guide``: :data:`~protorch.control.teleop_guide.GUIDE_DEFAULTS`; ``teleop``:
    :data:`TELEOP_DEFAULTS` (``wall``: :data:`~protorch.tasks.teleop_trials.SCHEDULE_DEFAULTS`).
    """
    task, gp, demos, promp, loop, guide, teleop = (
        dict(x or {}) for x in (task, gp, demos, promp, loop, guide, teleop)
    )
    task.pop("_target_", None)
    beam, tele, op_cls, guide_cfg = _settings(
        task, demos, loop, gp, guide, teleop, list(freedom_optimizers)
    )
    opt = dict(optimizer)
    opt_name = opt.pop("name", "pro")
    if opt_name not in OPTIMIZERS:
        _refuse(f"optimizer.name={opt_name!r} is no optimiser")
    threads = None if num_threads is None else check_int(num_threads, "num_threads", 1)
    with torch_threads(threads):
        return _run(
            Path(out_dir),
            seed,
            beam,
            tele,
            op_cls,
            guide_cfg,
            opt_name,
            opt,
            gp,
            demos,
            promp,
            loop,
            list(freedom_optimizers),
            plot,
        )


def _run(
    out_dir,
    seed,
    beam,
    tele,
    op_cls,
    guide_cfg,
    opt_name,
    opt_kw,
    gp,
    demos,
    promp_cfg,
    loop,
    freedom_opts,
    plot,
) -> dict:
    t_start = time.perf_counter()
    gen = torch.Generator().manual_seed(int(seed) + _DEMO_SEED)
    trajs, envs = careful_demonstrations(
        beam, int(demos.get("envs", 6)), int(demos.get("per_env", 3)), gen
    )
    labels = beam.label(torch.stack(trajs), envs)
    promp = ProMP(7, int(promp_cfg.get("num_basis", 10)), int(promp_cfg.get("num_steps", 100)))
    test = beam.sample_envs(50, torch.Generator().manual_seed(_TEST_SEED))
    maps, metrics = {}, {"map": {}, "teleop": {}, "freedom": {}}
    for name in [opt_name] + [o for o in freedom_opts if o != opt_name]:
        kw = opt_kw if name == opt_name else {k: opt_kw[k] for k in _PEER_KEYS if k in opt_kw}
        t0 = time.perf_counter()
        env_map, var_map, res = build_map(
            beam,
            promp,
            trajs,
            envs,
            labels,
            optimizer=name,
            optimizer_kwargs=kw,
            gp=gp,
            loop=loop,
            seed=int(seed),
        )
        maps[name] = (env_map, var_map)
        held = {}
        for k in (0, 1):
            tr = promp.trajectory(env_map.predict_mean(test, k))
            held[f"class{k}_mean_success_rate"] = float(beam.success(tr, test).double().mean())
        metrics["map"][name] = {
            "seconds": round(time.perf_counter() - t0, 3),
            "entries": int(env_map.E.shape[0]),
            "loop_success_rate": res.success_rate,
            **held,
            "mean_std": float(var_map.MU.exp().sqrt().mean()),
        }
    env_map, var_map = maps[opt_name]  # what the browser page guides with (protorch.view.teleop)
    out_dir.mkdir(parents=True, exist_ok=True)
    env_map.save(out_dir / MAP_FILE)
    var_map.save(out_dir / VAR_MAP_FILE)
    n = tele["operators"]
    walls = draw_schedules(beam, n, tele["wall_seed"], **dict(tele["wall"]))
    run_kw = dict(dt=float(tele["dt"]), time_limit=float(tele["time_limit"]))

    def operators():
        ops = [op_cls(i) for i in range(n)]
        for o in ops:
            if hasattr(o, "bind"):
                o.bind(beam)
        return ops

    start, end = beam.endpoint_poses()
    guides = {
        name: MixtureGuide(promp, m, v, [0, 1], end[:3] - start[:3], **guide_cfg)
        for name, (m, v) in maps.items()
    }
    results = {}
    for cond in tele["conditions"]:
        r = run_trials(beam, operators(), walls, cond, guides[opt_name], record=plot, **run_kw)
        results[cond] = r
        metrics["teleop"][cond] = _condition_metrics(r)
    for name in maps:  # the freedom of each optimiser's adaptive guide on the same trials
        r = (
            results["adaptive"]
            if name == opt_name and "adaptive" in results
            else run_trials(beam, operators(), walls, "adaptive", guides[name], **run_kw)
        )
        metrics["freedom"][name] = {
            "freedom": float(r["freedom"].mean()),
            "success_rate": float(r["success"].double().mean()),
            "effort": float(r["effort"].mean()),
        }
    if plot:
        teleop_figure(out_dir / "teleop_trials.png", beam, results)
    metrics["settings"] = {
        "optimizer": opt_name,
        "operator": str(tele["operator"]),
        "operators": n,
        "wall_seed": tele["wall_seed"],
        "wall": {**SCHEDULE_DEFAULTS, **dict(tele["wall"])},
        "dt": run_kw["dt"],
        "time_limit": run_kw["time_limit"],
    }
    metrics["seconds"] = round(time.perf_counter() - t_start, 3)
    return metrics
