"""The Hydra command line: ``python -m protorch experiment=fig4_window [key=value ...]``.

A thin edge: :func:`main` answers ``--help`` (and a command line naming no experiment) with
:mod:`protorch.app.help`, otherwise Hydra composes the config and :func:`hydra_app` resolves it
to a plain dict and calls :func:`protorch.experiments.run_experiment`, then prints the run's
summary (headline numbers, status, run folder, wall times) as its last lines, through the
``protorch`` logger, so the run folder's ``main.log`` holds them too. A refused value (a bad
setting, a task breaking its contract) is one line on stderr, exit status 2, and leaves no run
folder; a failed run is one line on stderr, exit status 1, its traceback in ``main.log`` and
``status.json`` (``HYDRA_FULL_ERROR=1`` raises instead). Nothing else in the package imports
Hydra. The app returns the number named by the config's ``objective`` key (e.g.
``test.success_rate`` for ``experiment=point_particle``), which is what a sweeper such as Optuna
optimises.
"""

from __future__ import annotations

import logging
import os
import shutil
import sys
import time
import traceback
from pathlib import Path
from typing import Any, cast

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from ..data.files import atomic_write_bytes
from ..experiments import REFUSED, check_config, run_experiment
from ..experiments.run_folder import check_run_folder
from ..experiments.summary import format_summary
from ..view.__main__ import main as view_main
from .help import help_text, wants_help

LOG = logging.getLogger("protorch")

# ``${protorch.or:${a},default}``: ``a`` unless it is null (a baseline keeps a number where the main
# optimiser's setting is null, e.g. EPRO's self-set beta)
if not OmegaConf.has_resolver("protorch.or"):
    OmegaConf.register_new_resolver(
        "protorch.or", lambda value, default: default if value is None else value
    )


def config_dir() -> Path:
    """``conf/`` beside the package in a source checkout, ``protorch/conf`` in an
    installed wheel."""
    package = Path(__file__).resolve().parent.parent
    for candidate in (package / "conf", package.parent / "conf"):
        if (candidate / "config.yaml").is_file():
            return candidate
    raise FileNotFoundError(f"protorch's Hydra configs were not found beside {package}")


class BelowWarning(logging.Filter):
    """The console's stdout handler takes the lines below WARNING; stderr takes the rest
    (conf/hydra/job_logging/protorch.yaml)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno < logging.WARNING


def _only_hydra_files(out_dir: Path) -> bool:
    """Whether ``out_dir`` holds nothing but what Hydra wrote for this job (``.hydra/``, the job's
    log)."""
    return out_dir.is_dir() and {p.name for p in out_dir.iterdir()} <= {
        ".hydra",
        f"{HydraConfig.get().job.name}.log",
    }


def _refuse(
    exc: Exception, out_dir: Path, *, remove: bool, config_before: bytes | None = None
) -> None:
    """A value refused before any work: one line on stderr and exit status 2
    (``HYDRA_FULL_ERROR=1``:
    the traceback instead); the run folder Hydra made for it removed when it holds nothing else, a
    reused folder's ``config.yaml`` put back as it was."""
    if os.environ.get("HYDRA_FULL_ERROR") == "1":
        raise exc
    if remove:
        shutil.rmtree(out_dir, ignore_errors=True)
        if (
            out_dir.parent != Path.cwd()
            and out_dir.parent.is_dir()
            and not any(out_dir.parent.iterdir())
        ):
            out_dir.parent.rmdir()  # e.g. runs/, which Hydra made for this run alone
    elif config_before is not None:
        atomic_write_bytes(out_dir / "config.yaml", config_before)
    LOG.error("error: " + " ".join(str(exc).split()))
    sys.exit(2)


@hydra.main(version_base=None, config_path=str(config_dir()), config_name="config")
def hydra_app(cfg: DictConfig) -> float | None:
    # matplotlib's INFO lines (e.g. the GIF writer it picks) are not the run's log
    logging.getLogger("matplotlib").setLevel(logging.WARNING)
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    fresh = _only_hydra_files(out_dir)
    plain = cast(dict[str, Any], OmegaConf.to_container(cfg, resolve=True))  # cfg is a mapping
    try:
        check_config(plain)  # every setting, before any file is written
        check_run_folder(out_dir, plain["name"])  # before config.yaml replaces another experiment's
    except ValueError as exc:  # SettingsError, or a folder holding another experiment's results
        _refuse(exc, out_dir, remove=fresh)
    name = plain["name"]
    config_path = out_dir / "config.yaml"
    config_before = config_path.read_bytes() if config_path.is_file() else None
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(config_path, OmegaConf.to_yaml(OmegaConf.create(plain)).encode())
    logging.getLogger("protorch.details").info(
        f"[protorch] {name}: seed {plain.get('seed')}, threads "
        f"{plain.get('threads')}, run folder {out_dir}"
    )  # main.log only
    t0 = time.perf_counter()
    try:
        metrics = run_experiment(plain, out_dir)
    except REFUSED as exc:  # e.g. a task whose costs return the wrong shape: one line, no traceback
        _refuse(exc, out_dir, remove=fresh, config_before=config_before)
    except Exception as exc:
        if os.environ.get("HYDRA_FULL_ERROR") == "1":
            raise
        logging.getLogger("protorch.details").error(traceback.format_exc())  # main.log only
        LOG.error(
            f"[protorch] {name} FAILED after {time.perf_counter() - t0:.1f} s: "
            f"{type(exc).__name__}: "
            f"{' '.join(str(exc).split())} (traceback in {out_dir / 'main.log'}; "
            f"{out_dir / 'status.json'}; "
            "HYDRA_FULL_ERROR=1 prints it)"
        )
        sys.exit(1)
    LOG.info(format_summary(name, metrics["summary"]))
    objective = metrics.get("objective")
    return None if objective is None else objective["value"]


def pin_mkl_code_path() -> str:
    """Pin MKL's code path to its AVX2 branch (conditional numerical reproducibility,
    ``MKL_CBWR=AVX2``) unless the user chose one; returns the setting in effect.

    MKL picks its kernels by CPU (AVX2, AVX-512, ...) and their last bits differ (its Cholesky
    and triangular solves, which the GP map runs in float64); the loop amplifies a flipped bit
    into another solved environment, so the same command gave other success rates on another
    machine. ATen's own kernels give the same bits on the AVX2 and AVX-512 paths
    (docs/reproducibility.md). MKL reads the variable at its first call, which protorch's imports
    never make (tests/app/test_main.py checks it); a CPU without AVX2 keeps MKL's own choice."""
    return os.environ.setdefault("MKL_CBWR", "AVX2")


def main() -> float | None:
    """``python -m protorch`` and the ``protorch`` command: ``protorch view [RUN_DIR] ...`` serves
    the live viewer (:mod:`protorch.view`); ``--help`` or no ``experiment=`` prints the help;
    anything else goes to the Hydra app (:func:`hydra_app`)."""
    pin_mkl_code_path()
    if len(sys.argv) > 1 and sys.argv[1] == "view":
        sys.exit(view_main(sys.argv[2:]))
    if wants_help(sys.argv[1:]):
        print(help_text(config_dir(), sys.argv[1:]))
        return None
    return hydra_app()


cli = main  # the console script's entry point
