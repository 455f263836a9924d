"""The experiments' settings for the benchmarks, composed the way ``python -m protorch`` does.

The values live in config groups (``conf/optimizer``, ``conf/gp``, ``conf/task``) chosen by the
experiment's defaults list and overlaid by ``conf/experiment/<name>.yaml``; reading that file
alone misses them. :func:`experiment_settings` composes ``experiment=<name>`` plus overrides with
Hydra's compose API and returns the keyword arguments the app passes to the experiment's ``run``
(:func:`protorch.experiments.check_config`: every setting checked, groups overlaid).
"""

from __future__ import annotations

import inspect
from typing import Callable, Sequence

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from protorch.app.main import config_dir
from protorch.experiments import check_config


def experiment_config(name: str, overrides: Sequence[str] = ()) -> dict:
    """The composed, resolved config of ``experiment=<name>`` with ``overrides`` (Hydra syntax)."""
    with initialize_config_dir(config_dir=str(config_dir()), version_base=None):
        cfg = compose(config_name="config", overrides=[f"experiment={name}", *overrides])
    plain = OmegaConf.to_container(cfg, resolve=False)
    plain.pop("hydra", None)  # its ${hydra:...} values resolve only inside a Hydra run
    return OmegaConf.to_container(OmegaConf.create(plain), resolve=True)


def experiment_settings(name: str, overrides: Sequence[str] = ()) -> dict:
    """The keyword arguments ``python -m protorch experiment=<name> <overrides>`` runs with."""
    return check_config(experiment_config(name, overrides))


def arguments_of(fn: Callable, settings: dict) -> dict:
    """The entries of ``settings`` that ``fn`` (e.g. an experiment's ``prepare``) accepts."""
    accepted = inspect.signature(fn).parameters
    if any(p.kind is p.VAR_KEYWORD for p in accepted.values()):
        raise TypeError(f"{fn.__qualname__} takes **kwargs: give its settings explicitly")
    return {k: v for k, v in settings.items() if k in accepted}
