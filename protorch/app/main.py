"""The Hydra command line: ``python -m protorch experiment=fig4_window [key=value ...]``.

A thin edge: :func:`main` answers ``--help`` (and a command line naming no experiment) with
:mod:`protorch.app.help`, otherwise Hydra composes the config and :func:`hydra_app` resolves it
to a plain dict and calls :func:`protorch.experiments.run_experiment`, then prints the run's
summary (headline numbers, status, run folder, wall time) as its last lines. Nothing else in the
package imports Hydra. The app returns the number named by the config's ``objective`` key (e.g.
``test.success_rate`` for ``experiment=point_particle``), which is what a sweeper such as Optuna
optimises.
"""

from __future__ import annotations

import logging
import os
import sys
import time
import traceback
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from ..data.files import atomic_write_bytes
from ..experiments import SettingsError, check_config, run_experiment
from ..experiments.run_folder import check_run_folder
from ..experiments.summary import build_summary, format_summary
from ..view.__main__ import main as view_main
from .help import help_text, wants_help


# ``${protorch.or:${a},default}``: ``a`` unless it is null (a baseline keeps a number where the main
# optimiser's setting is null, e.g. EPRO's self-set beta)
if not OmegaConf.has_resolver("protorch.or"):
    OmegaConf.register_new_resolver("protorch.or", lambda value, default: default if value is None else value)


def config_dir() -> Path:
    """``conf/`` beside the package in a source checkout, ``protorch/conf`` in an installed wheel."""
    package = Path(__file__).resolve().parent.parent
    for candidate in (package / "conf", package.parent / "conf"):
        if (candidate / "config.yaml").is_file():
            return candidate
    raise FileNotFoundError(f"protorch's Hydra configs were not found beside {package}")


@hydra.main(version_base=None, config_path=str(config_dir()), config_name="config")
def hydra_app(cfg: DictConfig) -> float | None:
    # matplotlib's INFO lines (e.g. the GIF writer it picks) are not the run's log
    logging.getLogger("matplotlib").setLevel(logging.WARNING)
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    plain = OmegaConf.to_container(cfg, resolve=True)
    try:
        check_config(plain)  # every setting, before any file is written
    except SettingsError as exc:
        if os.environ.get("HYDRA_FULL_ERROR") == "1":
            raise
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
    name = plain["name"]
    try:
        check_run_folder(out_dir, name)  # before config.yaml replaces another experiment's
    except ValueError as exc:
        if os.environ.get("HYDRA_FULL_ERROR") == "1":
            raise
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out_dir / "config.yaml", OmegaConf.to_yaml(OmegaConf.create(plain)).encode())
    t0 = time.perf_counter()
    try:
        metrics = run_experiment(plain, out_dir)
    except Exception as exc:
        traceback.print_exc()
        summary = build_summary(name, {}, run_dir=out_dir, wall_seconds=time.perf_counter() - t0,
                                status="failed", error=f"{type(exc).__name__}: {exc}")
        print(format_summary(name, summary), flush=True)
        print(f"[protorch] {name} FAILED: {type(exc).__name__}: {exc} (details in {out_dir / 'status.json'})",
              file=sys.stderr, flush=True)
        sys.exit(1)
    print(format_summary(name, metrics["summary"]), flush=True)
    objective = metrics.get("objective")
    return None if objective is None else objective["value"]


def main() -> float | None:
    """``python -m protorch`` and the ``protorch`` command: ``protorch view [RUN_DIR] ...`` serves
    the live viewer (:mod:`protorch.view`); ``--help`` or no ``experiment=`` prints the help;
    anything else goes to the Hydra app (:func:`hydra_app`)."""
    if len(sys.argv) > 1 and sys.argv[1] == "view":
        sys.exit(view_main(sys.argv[2:]))
    if wants_help(sys.argv[1:]):
        print(help_text(config_dir(), sys.argv[1:]))
        return None
    return hydra_app()


cli = main  # the console script's entry point
