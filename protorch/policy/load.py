"""``protorch.load(run)``: a run folder as a :class:`~protorch.policy.policy.Policy`, without Hydra
or OmegaConf: the run's resolved ``config.yaml`` read as plain YAML, the task rebuilt through the
experiment's own settings check and builder
(:func:`protorch.experiments.policy_run.rebuild_experiment`), the map from its checkpoint,
the class choice's settings from the moving test's."""

from __future__ import annotations

import re
from pathlib import Path

import torch

from ..data.checkpoint import checkpoint_path, load
from ..experiments.policy_run import rebuild_experiment
from .policy import Policy
from .settings import policy_settings

__all__ = ["CONFIG_FILE", "load_policy", "read_config"]

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
    settings from the run's ``config.yaml`` through the experiment's own builder. A folder without
    ``config.yaml`` (a checkpoint written by :func:`protorch.save_model`, a loop baseline's folder)
    gives the map alone (``task=None``). ``device``, ``dtype`` (float64 by default), ``backend``:
    of the map (as :func:`protorch.data.checkpoint.load`; the policy's per-call path is float64
    whatever the map's dtype). ``options`` override :class:`~protorch.policy.policy.Policy`'s
    settings (``planner``, ``duration``, ``switch_margin``, ``decision_dt``, ``blend``, ``check``,
    ``kp``, ``max_acceleration``, ``switch_clearance``, ``limits``, ``max_velocity``, ``max_jerk``).
    Raises ``FileNotFoundError`` (no such folder, no checkpoint) or ``ValueError`` (another
    experiment, a config this protorch refuses), each naming ``run=``."""
    dtype = torch.float64 if dtype is None else dtype
    p = Path(run)
    where = f"run={str(run)!r}"
    if not p.exists():
        raise FileNotFoundError(f"{where}: no such file or folder")
    config = p / CONFIG_FILE if p.is_dir() else None
    if config is None or not config.is_file():
        if not checkpoint_path(p).is_file():
            raise FileNotFoundError(
                f"{where} holds no checkpoint ({checkpoint_path(p)}) and no {CONFIG_FILE}: "
                "give a run folder of arm_reach, point_particle or self_improve"
            )
        model = load(p, device=device, dtype=dtype, backend=backend)
        return Policy(model.promp, model.env_map, model.task_name, warm_up=warm_up, **options)
    try:
        cfg = read_config(config)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    exp = rebuild_experiment(cfg, where)
    if not checkpoint_path(p).is_file():
        raise FileNotFoundError(
            f"{where} holds no checkpoint ({checkpoint_path(p)}): the run did not get to "
            "its loop; resume it"
        )
    try:
        model = load(
            p,
            device=device,
            dtype=dtype,
            backend=backend,
            promp={"num_dof": exp.num_dof(), **exp.promp_cfg},
        )
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    task = exp.task
    if model.task_name and getattr(task, "name", model.task_name) != model.task_name:
        raise ValueError(
            f"{where}: its checkpoint is of task {model.task_name!r} but config.yaml builds "
            f"{getattr(task, 'name', '?')!r}"
        )
    if hasattr(task, "to"):
        task.to(model.promp.basis.device)
    settings = policy_settings(cfg["name"], getattr(exp, "dyn_cfg", None), **options)
    with torch.no_grad():
        return Policy(
            model.promp,
            model.env_map,
            model.task_name,
            task=task,
            experiment=cfg["name"],
            warm_up=warm_up,
            **settings,
        )
