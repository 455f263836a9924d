"""Plumbing shared by the experiments: dtype names, seeding, atomic JSON output."""

from __future__ import annotations

import json
import math
from pathlib import Path

import torch

from ..checks import check_int
from ..data.files import atomic_write_bytes
from ..loop.settings import LOOP_GROUP, LoopSettings
from ..optim import CMAES, OPTIMIZERS, PRO, RWPO, RWR, optimizer_class

DTYPES = {"float32": torch.float32, "float64": torch.float64}


def resolve_dtype(name: str | torch.dtype) -> torch.dtype:
    if isinstance(name, torch.dtype):
        return name
    if name not in DTYPES:
        raise ValueError(f"dtype must be one of {sorted(DTYPES)}, got {name!r}")
    return DTYPES[name]


def demo_source(value) -> str | Path:
    """``task.demos``: ``"synthetic"``, or an existing folder (``~`` expanded) of demonstration
    files; anything else raises naming the setting."""
    if str(value) == "synthetic":
        return "synthetic"
    folder = Path(str(value)).expanduser()
    if not folder.is_dir():
        raise FileNotFoundError(
            f"task.demos={str(value)!r}: no such folder (resolved to {folder.resolve()}); "
            "give 'synthetic' or a folder of trajK.out / envK.out files"
        )
    return folder


def resolve_device(name: str | torch.device) -> torch.device:
    dev = torch.device(name)
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError("device 'cuda' was asked for but torch.cuda.is_available() is False")
    return dev


def _strict_json(x):
    """``x`` with every non-finite float (NaN, inf: not JSON) replaced by ``None`` (``null``)."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _strict_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_strict_json(v) for v in x]
    return x


def write_json(path: Path, data: dict) -> None:
    """Write ``data`` as standard JSON atomically (temp file in the same folder, then rename).

    A metric that is undefined (a rate over zero episodes, say: NaN) is written as ``null``, so
    every JSON reader (jq, JavaScript, pandas) can parse the file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps(_strict_json(data), indent=2, sort_keys=True, allow_nan=False)
    atomic_write_bytes(path, text.encode())  # mode 0644 under the usual umask, fsync-ed


def flatten_metrics(data: dict, prefix: str = "") -> dict:
    """Nested dicts -> ``{"a.b.c": leaf}``; lists and other leaves are kept as they are."""
    out: dict = {}
    for key, value in data.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten_metrics(value, path + "."))
        else:
            out[path] = value
    return out


def metric_value(metrics: dict, key: str) -> float:
    """The number at the dotted ``key`` of a (nested) metrics dict, e.g. ``"test.success_rate"``;
    a bool counts as 0 / 1. A missing or non-numeric entry raises an error listing the numeric
    keys."""
    node = metrics
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            node = None
            break
        node = node[part]
    if isinstance(node, (bool, int, float)) and not isinstance(node, str):
        return float(node)
    numeric = sorted(
        k for k, v in flatten_metrics(metrics).items() if isinstance(v, (bool, int, float))
    )
    what = "no such metric" if node is None else f"not a number ({type(node).__name__})"
    raise ValueError(
        f"objective {key!r}: {what}; numeric metrics of this run: {', '.join(numeric)}"
    )


def optimizer_kwargs(common: dict, specific: dict | None) -> dict:
    """The shared optimiser settings (beta, num_samples, ...) overlaid with a method's own."""
    out = {k: v for k, v in common.items() if not isinstance(v, dict)}
    out.update(specific or {})
    return out


SHARED_OPTIMIZER_KEYS = ("beta", "num_samples", "max_iter", "tol", "window")


def optimizer_label(name: str) -> str:
    """How summaries and figures name the optimiser registered as ``name`` (``"epro"`` ->
    ``"EPRO"``):
    its class name, CMA-ES spelled so; an unregistered name as it is."""
    cls = OPTIMIZERS.get(name)
    return "CMA-ES" if cls is CMAES else (str(name) if cls is None else cls.__name__)


def problem_arguments(cls: type, kwargs: dict, task, promp) -> dict:
    """``kwargs`` plus what ``cls`` needs to know of the problem and no config holds: RWPO's
    relevance search asks for the task's number of objectives and the ProMP's basis functions
    per DoF (a task without ``num_objectives`` leaves it to RWPO to say so)."""
    if not issubclass(cls, RWPO):
        return kwargs
    known = {"num_basis": promp.num_basis}
    if getattr(task, "num_objectives", None) is not None:
        known["num_objectives"] = task.num_objectives
    return {**known, **kwargs}


def optimizer_spec(optimizer: dict, default: type = PRO) -> tuple[type, dict]:
    """``(class, keyword arguments)`` of an optimizer group: ``{"name": <registered name>, ...}``
    (``conf/optimizer/<name>.yaml``), or the per-method form ``{shared keys, "pro": {...}, ...}``
    for ``default`` (PRO)."""
    if "name" in optimizer:
        return optimizer_class(optimizer["name"]), {
            k: v for k, v in optimizer.items() if k != "name"
        }
    return default, optimizer_kwargs(optimizer, optimizer.get(default.__name__.lower()))


def baseline_spec(optimizer: dict, baseline: dict | None, default: type = RWR) -> tuple[type, dict]:
    """The comparison optimiser: the ``baseline_optimizer`` group, or (without one) ``default``
    with ``optimizer``'s shared settings and its per-method section."""
    if baseline:
        return optimizer_spec(baseline, default)
    shared = {
        k: v for k, v in optimizer.items() if k in SHARED_OPTIMIZER_KEYS or not isinstance(v, dict)
    }
    shared.pop("name", None)
    if "name" in optimizer:
        shared = {k: v for k, v in shared.items() if k in SHARED_OPTIMIZER_KEYS}
    return default, {**shared, **(optimizer.get(default.__name__.lower()) or {})}


def per_method_form(optimizer: dict, baseline: dict | None) -> dict:
    """An optimizer group (and the comparison's) as ``{shared keys, "<name>": {its own keys}}``,
    the form of the paper-figure experiments' ``optimizer`` argument."""
    out = {k: v for k, v in optimizer.items() if k in SHARED_OPTIMIZER_KEYS}
    for group in (optimizer, baseline or {}):
        if (
            "name" in group
        ):  # its own keys, and the shared ones where they differ from the optimizer's
            own = {
                k: v
                for k, v in group.items()
                if k != "name" and (k not in SHARED_OPTIMIZER_KEYS or out.get(k, object()) != v)
            }
            out[group["name"]] = {**out.get(group["name"], {}), **own}
    return out


# ----------------------------------------------------------------------------- settings checks
def check_optimizer(optimizer: dict) -> None:
    """``beta > 0`` (reward-weighted optimisers; a registered optimiser may take no beta, or
    ``None`` where it sets its own); ``max_iter >= 1`` and ``num_samples >= 2`` where given."""
    if "name" in optimizer and optimizer.get("beta") is None:
        pass
    elif "beta" not in optimizer or not float(optimizer["beta"]) > 0:
        raise ValueError(f"optimizer.beta must be > 0, got {optimizer.get('beta')}")
    for k, lo in (("max_iter", 1), ("num_samples", 2)):
        if k in optimizer:
            check_int(optimizer[k], f"optimizer.{k}", lo)


def gp_settings(
    gp_cfg: dict, *, alpha: float, var_floor: float, nearest_k: int | None
) -> tuple[str, float, float, dict]:
    """``(backend, alpha, var_floor, map options)`` of an experiment's ``gp`` group,
    with defaults."""
    a = float(gp_cfg.get("alpha", alpha))
    if not a > 0:
        raise ValueError(f"gp.alpha must be > 0, got {gp_cfg.get('alpha')}")
    vf = float(gp_cfg.get("var_floor", var_floor))
    if not vf >= 0:
        raise ValueError(f"gp.var_floor must be >= 0, got {vf}")
    k, backend = gp_cfg.get("nearest_k", nearest_k), gp_cfg.get("backend", "torch")
    options = {} if k is None else {"nearest_k": k}
    if gp_cfg.get("neighbours") is not None:
        if backend != "sparse":
            raise ValueError(f"gp.neighbours applies to gp=sparse only, not to gp={backend}")
        options["neighbours"] = gp_cfg["neighbours"]
    return backend, a, vf, options


def loop_settings(loop_cfg: dict, *, num_envs: int) -> LoopSettings:
    """The :class:`~protorch.loop.LoopSettings` of an experiment's ``loop`` group (its keys of
    :data:`~protorch.loop.settings.LOOP_GROUP`; the defaults are the dataclass's, ``num_envs``
    the experiment's), validated: a bad value raises one line naming ``loop.<key>``."""
    given = {k: loop_cfg[k] for k in LOOP_GROUP if k in loop_cfg}
    try:
        return LoopSettings(**{"num_envs": num_envs, **given})
    except ValueError as exc:
        raise ValueError(f"loop.{exc}") from None


def evaluation_settings(
    test_cfg: dict, dyn_cfg: dict, *, seed: int, demo_seed: int, test_seed: int, dynamic_seed: int
) -> tuple[int, int, int]:
    """``(number of held-out environments, their seed, the moving episodes' seed)`` from
    ``test.{num_envs, seed}`` and ``dynamic.seed`` (popped from ``dyn_cfg``, the rest of which
    goes to the episodes); the defaults are ``test_seed`` and ``dynamic_seed``, and neither seed
    may be a training seed (``seed`` and the demonstrations' ``demo_seed``)."""
    n = check_int(test_cfg.get("num_envs", 200), "test.num_envs", 1)
    training = (int(seed), int(demo_seed))
    seeds = [
        _held_out_seed(cfg.get("seed", default), where, seed=seed, training_seeds=training)
        for cfg, where, default in (
            (test_cfg, "test", test_seed),
            (dyn_cfg, "dynamic", dynamic_seed),
        )
    ]
    dyn_cfg.pop("seed", None)
    return n, seeds[0], seeds[1]


def _held_out_seed(value, where: str, *, seed: int, training_seeds: tuple[int, ...]) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{where}.seed must be an integer, got {value!r}")
    if value in training_seeds:
        raise ValueError(
            f"{where}.seed ({value}) must differ from the training seeds (seed={seed})"
        )
    return int(value)
