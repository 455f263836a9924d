"""``protorch.load(run)``: a run folder as a :class:`~protorch.policy.policy.Policy`, without Hydra,
OmegaConf or the experiments: the run's ``policy.json`` (written by the run,
:func:`protorch.experiments.policy_run.write_policy_record`) names the task's class and its
constructor's arguments, the ProMP's size and the policy's settings (the motion's duration, the
class choice's); the map comes from its checkpoint. A run folder without ``policy.json`` (written
before it, or a run killed before its end) is rebuilt from its resolved ``config.yaml`` through the
experiment's own settings check and builder
(:func:`protorch.experiments.policy_run.rebuild_experiment`, imported then)."""

from __future__ import annotations

import importlib
import json
import logging
import re
from pathlib import Path

import torch

from ..data.checkpoint import checkpoint_path, load
from ..tasks import make_task
from .policy import Policy

__all__ = ["CONFIG_FILE", "POLICY_FILE", "load_policy", "read_config", "read_policy_record"]

POLICY_FILE = "policy.json"  # a run folder's policy record
RECORD_FORMAT = 1  # policy.json's format: a record of another format is refused

CONFIG_FILE = (
    "config.yaml"  # a run folder's resolved settings (protorch.experiments.run_folder.CONFIG_FILE)
)


def _loader():
    """PyYAML's safe loader reading ``1e-3`` as a float, as OmegaConf (which wrote the file) does
    (YAML 1.1 alone reads a float without a dot as a string)."""
    import yaml

    class Loader(yaml.SafeLoader):
        pass

    Loader.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(
            r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                    |\.[0-9_]+(?:[eE][-+][0-9]+)?
                    |[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+\.[0-9_]*
                    |[-+]?\.(?:inf|Inf|INF)
                    |\.(?:nan|NaN|NAN))$""",
            re.VERBOSE,
        ),
        list("-+0123456789."),
    )
    return Loader


def read_config(path: Path) -> dict:
    """A run's resolved ``config.yaml`` as a dict; ``ValueError`` if it is not one."""
    import yaml

    try:
        cfg = yaml.load(Path(path).read_text(), Loader=_loader())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"{path} is not a readable config ({exc})") from None
    if not isinstance(cfg, dict):
        raise ValueError(f"{path} is not a readable config (not a mapping)")
    return cfg


def load_policy(
    run, *, device=None, dtype=None, backend: str | None = None, warm_up: bool = True, **options
):
    """A run folder as a :class:`~protorch.policy.policy.Policy` (``protorch.load``): the map
    from ``checkpoint/``, the task, the ProMP's size, the motion's duration and the class choice's
    settings from the run's ``policy.json`` (a run without one: from its ``config.yaml`` through the
    experiment's own builder). A folder without ``policy.json`` and ``config.yaml`` (a
    checkpoint written by :func:`protorch.save_model`, a loop baseline's folder) gives the map
    alone (``task=None``). ``device``, ``dtype`` (float64 by default), ``backend``:
    of the map (as :func:`protorch.data.checkpoint.load`; the policy's per-call path is float64
    whatever the map's dtype). ``options`` override :class:`~protorch.policy.policy.Policy`'s
    settings (``planner``, ``duration``, ``switch_margin``, ``decision_dt``, ``blend``, ``check``,
    ``kp``, ``max_acceleration``, ``switch_clearance``, ``limits``, ``max_velocity``, ``max_jerk``;
    ``limits`` is not a run's setting: ``"auto"``, the robot's limits with ``planner="thread"``
    or ``"process"``, unless given).
    Raises ``FileNotFoundError`` (no such folder, no checkpoint) or ``ValueError`` (another
    experiment, a config this protorch refuses), each naming ``run=``."""
    dtype = torch.float64 if dtype is None else dtype
    p = Path(run)
    where = f"run={str(run)!r}"
    if not p.exists():
        raise FileNotFoundError(f"{where}: no such file or folder")
    config = p / CONFIG_FILE if p.is_dir() else None
    if config is None or not (config.is_file() or (p / POLICY_FILE).is_file()):
        if not checkpoint_path(p).is_file():
            raise FileNotFoundError(
                f"{where} holds no checkpoint ({checkpoint_path(p)}) and no {CONFIG_FILE}: "
                "give a run folder of arm_reach, point_particle or self_improve"
            )
        model = load(p, device=device, dtype=dtype, backend=backend)
        return Policy(model.promp, model.env_map, model.task_name, warm_up=warm_up, **options)
    record = p / POLICY_FILE
    if record.is_file():
        try:
            rec = read_policy_record(record)
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
        experiment, promp_cfg, settings = rec["experiment"], rec["promp"], rec["policy"]
        try:
            task = make_task(rec["task"]["class"], **_tuples(rec["task"]["kwargs"]))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: its {POLICY_FILE} builds no task ({exc})") from None
    else:
        experiment, task, promp_cfg, settings = _from_config(config, where)
    if not checkpoint_path(p).is_file():
        raise FileNotFoundError(
            f"{where} holds no checkpoint ({checkpoint_path(p)}): the run did not get to "
            "its loop; resume it"
        )
    try:
        model = load(p, device=device, dtype=dtype, backend=backend, promp=promp_cfg)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    if model.task_name and getattr(task, "name", model.task_name) != model.task_name:
        raise ValueError(
            f"{where}: its checkpoint is of task {model.task_name!r} but its settings build "
            f"{getattr(task, 'name', '?')!r}"
        )
    if hasattr(task, "to"):
        task.to(model.promp.basis.device)
    with torch.no_grad():
        return Policy(
            model.promp,
            model.env_map,
            model.task_name,
            task=task,
            experiment=experiment,
            warm_up=warm_up,
            **{**settings, **options},
        )


def _tuples(kwargs: dict) -> dict:
    """JSON's lists as tuples, as the experiments pass a config's sequences to a task."""
    return {k: (tuple(v) if isinstance(v, list) else v) for k, v in kwargs.items()}


def read_policy_record(path: Path) -> dict:
    """A run's ``policy.json``; ``ValueError`` naming the file if it is not one of this format."""
    try:
        rec = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path} is not a readable policy record ({exc})") from None
    keys = ("experiment", "task", "promp", "policy")
    if not isinstance(rec, dict) or rec.get("format") != RECORD_FORMAT:
        raise ValueError(
            f"{path}: a policy record of format {RECORD_FORMAT} expected, got "
            f"{rec.get('format') if isinstance(rec, dict) else rec!r}; re-run the experiment"
        )
    missing = [k for k in keys if k not in rec]
    if missing:
        raise ValueError(f"{path}: a policy record without {', '.join(missing)}")
    return rec


def _from_config(config: Path, where: str):
    """``(experiment, task, ProMP settings, policy settings)`` of a run without ``policy.json``,
    from its ``config.yaml`` through the experiment's own builder (this imports the
    experiments)."""
    logging.getLogger(__name__).info(
        "%s has no %s (a run from before it, or one that did not finish): rebuilding its task "
        "from config.yaml through the experiment's builder (imports protorch.experiments)",
        where,
        POLICY_FILE,
    )
    try:
        cfg = read_config(config)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    # the one import of the experiments from the core, by name so it stays out of `import protorch`
    rebuild = importlib.import_module("protorch.experiments.policy_run").rebuild_experiment
    registry = importlib.import_module("protorch.experiments.registry").REGISTRY
    exp = rebuild(cfg, where)
    settings = registry[cfg["name"]].policy_settings(getattr(exp, "dyn_cfg", None))
    return cfg["name"], exp.task, {"num_dof": exp.num_dof(), **exp.promp_cfg}, settings
