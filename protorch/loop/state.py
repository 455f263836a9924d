"""The loop's run state: what makes a run the same run (its signature), the steps done, the
checkpoint that holds both, and resuming from it.

The checkpoint is ``<run_dir>/checkpoint/dataset.safetensors`` (the data set, written by
:func:`protorch.data.checkpoint.save_model`, so :func:`protorch.load` rebuilds the map) with the
run state (step, environments tried, metrics rows, elapsed seconds, signature) in the same
file's metadata, so data set and state can never disagree. ``<run_dir>/loop_metrics.csv`` is
rewritten atomically from the same rows at the same moment.
"""

from __future__ import annotations

import copy
import csv
import io
import math
import os
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import torch
from torch import Tensor

from ..data.checkpoint import checkpoint_path
from ..data.dataset import TrajectoryDataset
from ..data.files import atomic_write_bytes
from .inflight import read_inflight, remove_inflight, write_inflight
from .settings import LoopSettings

__all__ = [
    "LOOP_STATE_VERSION",
    "METRICS_FILE",
    "METRIC_FIELDS",
    "RunState",
    "run_signature",
    "writable_folder",
]

LOOP_STATE_VERSION = 1
METRICS_FILE = "loop_metrics.csv"
# one row per step (step 0: the initial data set, before any environment was tried)
METRIC_FIELDS = (
    "step",
    "envs_done",
    "dataset_size",
    "batch",
    "added",
    "initial_success",
    "success",
    "converged",
    "iterations_mean",
    "iterations_max",
    "rollouts",
    "eval_success",
    "success_rate",
    "seconds",
)


def jsonable(x):
    """Settings as the JSON of the checkpoint holds them (tuples as lists, other
    objects by repr)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in sorted(x.items())}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if x is None or isinstance(x, (bool, int, str)):
        return x
    if isinstance(x, float):
        return x if math.isfinite(x) else repr(x)
    if isinstance(x, Tensor) and x.numel() == 1:
        return jsonable(x.item())
    return repr(x)


def run_signature(
    settings: LoopSettings,
    optimizer: type,
    optimizer_kwargs: dict,
    env_map,
    eval_dtype: torch.dtype,
    *,
    solved: bool,
    labels: bool,
) -> dict:
    """Every setting that changes what the loop computes, as JSON: a resumed run must have the
    same one (``env_map``: the empty map, whose backend, alpha and options count)."""
    sig = {
        "num_envs": settings.num_envs,
        "batch_size": settings.batch_size,
        "seed": int(settings.seed),
        "choice": settings.choice,
        "add_only": settings.add_only,
        "optimizer": optimizer.__name__,
        "optimizer_kwargs": jsonable(optimizer_kwargs),
        "env_map": jsonable(
            {"backend": env_map.backend, "alpha": env_map.alpha, **env_map.options()}
        ),
        "min_var": float(settings.min_var),
        "var_floor": float(settings.var_floor),
        "sample_steps": settings.sample_steps,
        "eval_dtype": str(eval_dtype),
        "solved": bool(solved),
    }
    if labels:
        sig["labels"] = True
    if settings.each_label:
        sig["each_label"] = True
    if settings.refill:
        sig["refill"] = True
        if settings.refill_group != 1:
            sig["refill_group"] = settings.refill_group
    return sig


def writable_folder(folder: str | Path) -> Path:
    """``folder`` as a ``Path``, created if missing, after checking that a file can be written in
    it (a probe file created exclusively and removed); ``PermissionError`` naming the folder
    otherwise. Its ``checkpoint`` sub-folder, if present, is probed the same way."""
    folder = Path(folder)
    for f in (folder, checkpoint_path(folder).parent):
        if f != folder and not f.is_dir():
            continue
        try:
            f.mkdir(parents=True, exist_ok=True)
            fd, probe = tempfile.mkstemp(dir=f, prefix=".write-probe.", suffix=".tmp")
            os.close(fd)
            os.unlink(probe)
        except OSError as exc:
            raise PermissionError(f"run_dir: cannot write in {f} ({exc.strerror or exc})") from exc
    return folder


def same_data(given: TrajectoryDataset, saved: TrajectoryDataset, n: int) -> bool:
    """Whether ``given`` is the first ``n`` entries of ``saved`` (up to round-off)."""
    if len(given) != n or len(saved) < n:
        return False
    pairs = ((given.env, saved.env[:n]), (given.mean, saved.mean[:n]), (given.var, saved.var[:n]))
    return all(
        a.shape == b.shape and torch.allclose(a, b.to(a), rtol=1e-6, atol=1e-9) for a, b in pairs
    ) and torch.equal(given.label, saved.label[:n].to(given.label))


def write_metrics_csv(path: Path, rows: list[dict]) -> None:
    """``rows`` (keys :data:`METRIC_FIELDS`) as a CSV file, written atomically."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=METRIC_FIELDS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if row.get(k) is None else row.get(k)) for k in METRIC_FIELDS})
    atomic_write_bytes(path, buf.getvalue().encode())


@dataclass
class RunState:
    """Where a run stands: its ``signature`` (:func:`run_signature`), the ``step`` done, the pool
    indices ``tried`` so far, one metrics row per step (row 0: the initial data set), and the
    seconds spent by earlier (resumed) processes.

    ``save`` writes the data set with the map's settings (``save_model``'s signature); ``None``
    ``run_dir``: nothing is written. ``inflight``, set by a loop with work in flight between its
    checkpoints (the refill loop), returns that work's ``(tensors, meta)`` (or ``None``: none);
    each checkpoint writes it beside the data set (:mod:`.inflight`), and :meth:`resume` reads it
    back into ``restored``.
    """

    signature: dict
    run_dir: Path | None
    save: Callable
    step: int = 0
    tried: list[int] = field(default_factory=list)
    rows: list[dict] = field(default_factory=list)
    seconds_before: float = 0.0
    resumed_from: int | None = None
    started: float = field(default_factory=time.perf_counter)
    inflight: Callable[[], tuple[dict, dict] | None] | None = None
    restored: tuple[dict, dict] | None = None

    @property
    def checkpoint_file(self) -> Path | None:
        return None if self.run_dir is None else checkpoint_path(self.run_dir)

    @property
    def successes(self) -> int:
        """Successful environments over all steps so far."""
        return sum(int(r.get("success") or 0) for r in self.rows)

    def elapsed(self) -> float:
        """The run's seconds so far, earlier (resumed) processes included."""
        return self.seconds_before + time.perf_counter() - self.started

    def start(self, dataset: TrajectoryDataset, promp, *, resume: bool) -> TrajectoryDataset:
        """The data set this run grows: a copy of ``dataset`` (the caller's is left alone), or,
        with ``resume`` and a checkpoint in ``run_dir``, the checkpoint's (and the state it holds).
        An existing checkpoint without ``resume`` is an error (never overwritten)."""
        ckpt = self.checkpoint_file
        if ckpt is None or not ckpt.is_file():
            return copy.deepcopy(dataset)
        if not resume:
            raise FileExistsError(
                f"{ckpt} already exists: pass resume=True to continue that run, or choose another "
                "run directory"
            )
        return self.resume(dataset, promp)

    def resume(self, dataset: TrajectoryDataset, promp) -> TrajectoryDataset:
        """Load the checkpoint's data set and state; refuse one of another run (other settings or
        another initial data set than ``dataset``)."""
        ckpt = self.checkpoint_file
        loaded = TrajectoryDataset.load(ckpt, promp=promp, task_name=dataset.task_name)
        state = loaded.metadata.get("loop")
        if not state or state.get("version") != LOOP_STATE_VERSION:
            raise ValueError(f"{ckpt} holds no loop state this protorch can resume from")
        saved, now = state["signature"], self.signature
        if saved != now:
            diff = {
                k: (saved.get(k), now.get(k))
                for k in {**saved, **now}
                if saved.get(k) != now.get(k)
            }
            raise ValueError(
                f"cannot resume {ckpt}: it was started with other settings, (saved, now): {diff}"
            )
        initial = int(state["rows"][0]["dataset_size"]) if state["rows"] else 0
        if not same_data(dataset, loaded, initial):
            raise ValueError(
                f"cannot resume {ckpt}: its initial data set ({initial} entries) is not the one "
                "given now "
                f"({len(dataset)} entries); were the demonstrations or priors changed?"
            )
        self.tried, self.rows = list(state["tried"]), list(state["rows"])
        self.seconds_before, self.step = float(state["seconds"]), int(state["step"])
        record = state.get("inflight")
        self.restored = None if record is None else read_inflight(ckpt.parent, record)
        self.resumed_from = self.step
        self.started = time.perf_counter()
        return loaded

    def fit(self, env_map, dataset: TrajectoryDataset) -> None:
        """Fit the empty ``env_map`` to ``dataset``. Resumed: replay the initial fit and every
        step's adds, so the map is bit-identical to the one the killed run had (a single refit
        differs in round-off, and PRO amplifies that)."""
        if not self.rows:
            env_map.fit(dataset.env, dataset.mean, dataset.var, dataset.label)
            return
        # a step's adds: one (the step loop) or, with refill, one per finishing iteration ("adds")
        sizes = [int(self.rows[0]["dataset_size"])] + [
            int(n) for r in self.rows[1:] for n in r.get("adds", [r.get("added") or 0])
        ]
        if sum(sizes) != len(dataset):
            raise ValueError(
                f"{self.checkpoint_file}: the loop state does not match its data set "
                f"({sum(sizes)} != {len(dataset)})"
            )
        at = 0
        for k, n in enumerate(sizes):
            if n:
                sl = slice(at, at + n)
                args = (dataset.env[sl], dataset.mean[sl], dataset.var[sl], dataset.label[sl])
                if k == 0:
                    env_map.fit(*args)
                else:
                    env_map.add(*args)
            at += n

    def checkpoint(self, dataset: TrajectoryDataset, env_map) -> None:
        """Write the work in flight (if any, :mod:`.inflight`), the data set with this state in
        its metadata (naming that file), then ``loop_metrics.csv`` (each atomic; nothing without a
        ``run_dir``). The previous checkpoint's in-flight file is removed once the new data set is
        published, so a kill at any instant leaves a data set and the in-flight file it names."""
        if self.run_dir is None:
            return
        folder = checkpoint_path(self.run_dir).parent
        work = None if self.inflight is None else self.inflight()
        record = None if work is None else write_inflight(folder, self.step, *work)
        dataset.metadata["loop"] = {
            "version": LOOP_STATE_VERSION,
            "signature": self.signature,
            "step": self.step,
            "tried": self.tried,
            "rows": self.rows,
            "seconds": round(self.elapsed(), 3),
            **({} if record is None else {"inflight": record}),
        }
        self.save(
            self.run_dir,
            dataset,
            backend=env_map.backend,
            alpha=env_map.alpha,
            include_unconverged=True,
            **env_map.options(),
        )
        remove_inflight(folder, None if record is None else record["file"])
        write_metrics_csv(self.run_dir / METRICS_FILE, self.rows)
