"""The Hydra command line: ``python -m protorch experiment=fig4_window [key=value ...]``.

A thin edge: it composes the config, resolves it to a plain dict and calls
:func:`protorch.experiments.run_experiment`. Nothing else in the package imports Hydra.
It returns the number named by the config's ``objective`` key (e.g. ``test.success_rate`` for
``experiment=point_particle``), which is what a sweeper such as Optuna optimises.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from ..data.files import atomic_write_bytes
from ..experiments import SettingsError, check_config, run_experiment
from ..view.__main__ import main as view_main


def config_dir() -> Path:
    """``conf/`` beside the package in a source checkout, ``protorch/conf`` in an installed wheel."""
    package = Path(__file__).resolve().parent.parent
    for candidate in (package / "conf", package.parent / "conf"):
        if (candidate / "config.yaml").is_file():
            return candidate
    raise FileNotFoundError(f"protorch's Hydra configs were not found beside {package}")


@hydra.main(version_base=None, config_path=str(config_dir()), config_name="config")
def main(cfg: DictConfig) -> float | None:
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    plain = OmegaConf.to_container(cfg, resolve=True)
    try:
        check_config(plain)  # every setting, before any file is written
    except SettingsError as exc:
        if os.environ.get("HYDRA_FULL_ERROR") == "1":
            raise
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out_dir / "config.yaml", OmegaConf.to_yaml(OmegaConf.create(plain)).encode())
    metrics = run_experiment(plain, out_dir)
    print(f"[protorch] {plain['name']}: results in {out_dir}")
    objective = metrics.get("objective")
    return None if objective is None else objective["value"]


def cli():
    """The ``protorch`` console command: ``protorch view [RUN_DIR] ...`` serves the live viewer
    (:mod:`protorch.view`); anything else goes to the Hydra app (:func:`main`)."""
    if len(sys.argv) > 1 and sys.argv[1] == "view":
        sys.exit(view_main(sys.argv[2:]))
    return main()
