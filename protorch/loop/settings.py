"""The loop's settings, defined once: :class:`LoopSettings` (what the loop computes),
:class:`OptimizerSpec` (the optimiser and its keyword arguments) and :class:`Run` (where and how a
run is recorded), validated before any work.

Every field of :class:`LoopSettings` carries its one-line meaning and its allowed range in its
``metadata`` (``help``, ``ge``, ``gt``, ``choices``); the app's schema of the ``loop`` group
(:mod:`protorch.experiments.settings`) is generated from these fields, so the library and the app
share one set of names, meanings and defaults.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from ..checks import check_int

__all__ = [
    "ADD_ONLY",
    "CHOICES",
    "EVAL_DTYPES",
    "LOOP_GROUP",
    "LoopSettings",
    "OptimizerSpec",
    "Run",
]

ADD_ONLY = ("converged", "success", "all")
CHOICES = ("random", "nearest", "dataset")
EVAL_DTYPES = ("float32", "float64")
# the fields of LoopSettings an experiment's ``loop`` group sets (the app's schema of the group);
# seed and threads are top-level settings, var_floor is the map's (gp.var_floor), sample_steps and
# each_label the task's
LOOP_GROUP = (
    "num_envs",
    "batch_size",
    "add_only",
    "choice",
    "checkpoint_every",
    "eval_dtype",
    "min_var",
    "refill",
    "refill_group",
)


def _setting(default, help: str, *, ge=None, gt=None, choices=None) -> Any:
    """A field with its meaning and allowed range (read by the app's schema and ``--help``)."""
    meta = {"help": help, "ge": ge, "gt": gt, "le": None, "choices": choices}
    return dataclasses.field(default=default, metadata=meta)


@dataclass(frozen=True)
class LoopSettings:
    """The settings of :func:`~protorch.loop.self_improve`: which environments are tried, how
    many at once, which solutions are kept, in which dtype and on how many threads.

    Construction validates them (a clear ``ValueError`` naming the setting), stores the integers
    as ``int`` and ``eval_dtype`` by name (a ``torch.dtype`` is accepted). The defaults are the
    app's (``conf/experiment/*.yaml`` set them explicitly); ``batch_size=1, refill=False`` is the
    paper's sequential loop.
    """

    num_envs: int = _setting(1000, "environments the self-improvement loop tries", ge=0)
    batch_size: int = _setting(100, "B environments inferred and optimised at once", ge=1)
    add_only: str = _setting(
        "success",
        "which solutions join the data set: converged (the optimiser's flag, the authors' "
        "rule) | success (the optimised mean passes task.success) | all",
        choices=ADD_ONLY,
    )
    choice: str = _setting(
        "random",
        "order of the environments: pool order | nearest known first | the initial data "
        "set's own environments",
        choices=CHOICES,
    )
    each_label: bool = _setting(
        False, "with a labeller: optimise every known label's prediction for each environment"
    )
    sample_steps: int | None = _setting(
        None, "phases the optimiser's samples are evaluated at; null = the ProMP's T", ge=2
    )
    seed: int = _setting(0, "fixes the pool of environments and every step's optimiser seed")
    min_var: float = _setting(0.0, "floor on the inferred variance the optimiser starts from", ge=0)
    var_floor: float = _setting(0.0, "floor on the variance stored with a new entry", ge=0)
    checkpoint_every: int = _setting(1, "loop steps between atomic checkpoints", ge=1)
    refill: bool | str = _setting(
        "auto",
        "give a finished problem's slot the next environment at once (B workers); "
        "auto: where the optimiser can restart single problems (pro, rwr, cem)",
        choices=("auto",),
    )
    refill_group: int = _setting(
        1, "with refill: finished environments added and refilled once this many are done", ge=1
    )
    eval_dtype: str | None = _setting(
        "float32",
        "dtype of the optimiser's samples and costs; null = the ProMP's",
        choices=EVAL_DTYPES,
    )
    threads: int | str | None = _setting(
        "auto",
        "torch's CPU threads during the loop: an int, auto (the cores other programs leave "
        "free, re-chosen every step) or null (torch's setting)",
    )

    def __post_init__(self) -> None:
        if self.refill not in ("auto", True, False) or not isinstance(self.refill, (bool, str)):
            raise ValueError(f"refill must be auto, true or false, got {self.refill!r}")
        for name, lo in (
            ("num_envs", 0),
            ("batch_size", 1),
            ("checkpoint_every", 1),
            ("refill_group", 1),
        ):
            object.__setattr__(self, name, check_int(getattr(self, name), name, lo))
        if self.add_only not in ADD_ONLY:
            raise ValueError(f"add_only must be one of {list(ADD_ONLY)}, got {self.add_only!r}")
        if self.choice not in CHOICES:
            raise ValueError(f"choice must be one of {list(CHOICES)}, got {self.choice!r}")
        for name in ("min_var", "var_floor"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not float(v) >= 0:
                raise ValueError(f"{name} must be >= 0, got {v!r}")
            object.__setattr__(self, name, float(v))
        s = self.sample_steps
        if s is not None and (isinstance(s, bool) or int(s) != s or int(s) < 2):
            raise ValueError(f"sample_steps must be None or an int >= 2, got {s!r}")
        dt = self.eval_dtype  # a name, None or a torch.dtype
        dname = str(dt).removeprefix("torch.") if isinstance(dt, torch.dtype) else dt
        if dname is not None and dname not in EVAL_DTYPES:
            raise ValueError(f"eval_dtype must be one of {list(EVAL_DTYPES)} or None, got {dt!r}")
        object.__setattr__(self, "eval_dtype", dname)
        t = self.threads
        if not (t is None or t == "auto" or (isinstance(t, int) and not isinstance(t, bool))):
            raise ValueError(f"threads must be an int, 'auto' or None, got {t!r}")

    @property
    def torch_eval_dtype(self) -> torch.dtype | None:
        """``eval_dtype`` as a ``torch.dtype`` (``None``: the ProMP's)."""
        return None if self.eval_dtype is None else getattr(torch, self.eval_dtype)

    @property
    def num_steps(self) -> int:
        """Steps of the loop: ``ceil(num_envs / batch_size)`` (the last one may be smaller)."""
        return -(-self.num_envs // self.batch_size)

    def step_seed(self, step: int) -> int:
        """The optimiser's seed of step ``step``: a function of ``(seed, step)`` only, so a resumed
        run repeats what an uninterrupted one does."""
        return (int(self.seed) * 1_000_003 + int(step) * 7_919 + 17) % (2**63 - 1)

    def is_checkpoint_step(self, step: int) -> bool:
        """Whether the checkpoint is written after step ``step`` (every k-th and the last)."""
        return step % self.checkpoint_every == 0 or step == self.num_steps

    def replace(self, **changes) -> LoopSettings:
        """A copy with ``changes`` (validated again)."""
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class OptimizerSpec:
    """An optimiser class (``PRO``, ``RWR``, ...) and its keyword arguments (``beta``,
    ``num_samples``, ``max_iter``, ``tol``, ...; never ``seed``: the loop seeds every step).

    :meth:`of` also takes the class alone or ``functools.partial(cls, **kwargs)``.
    """

    cls: type
    kwargs: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.cls, type):
            raise TypeError(f"OptimizerSpec.cls must be an optimiser class, got {self.cls!r}")
        if "seed" in self.kwargs:
            raise ValueError(
                "the optimiser's kwargs must not hold 'seed': the loop seeds every step from "
                "(seed, step)"
            )
        object.__setattr__(self, "kwargs", dict(self.kwargs))

    @classmethod
    def of(cls, optimizer) -> OptimizerSpec:
        """``optimizer`` as a spec: an :class:`OptimizerSpec`, a class, or a
        ``functools.partial`` of a class with keyword arguments only."""
        if isinstance(optimizer, OptimizerSpec):
            return optimizer
        if isinstance(optimizer, functools.partial) and not optimizer.args:
            return cls(optimizer.func, dict(optimizer.keywords))  # type: ignore[arg-type]
        if isinstance(optimizer, type):
            return cls(optimizer)
        raise TypeError(
            "optimizer must be an optimiser class (PRO), OptimizerSpec(PRO, {...}) or "
            f"functools.partial(PRO, beta=...), got {optimizer!r}"
        )

    def build(self, mu, var, seed: int, **more):
        """The optimiser on ``mu`` / ``var`` ``(B, N)`` with the step's ``seed``."""
        return self.cls(mu, var, seed=seed, **self.kwargs, **more)


@dataclass(frozen=True)
class Run:
    """Where and how one run of the loop is recorded.

    ``dir``: where the checkpoint and ``loop_metrics.csv`` go (``None``: no files); created if
    missing and checked to be writable before any work. ``resume``: continue from its checkpoint
    (the same run, else an error names what differs); without it an existing checkpoint there is
    an error. ``progress``: a tqdm bar with the live success rate, titled ``desc``. ``on_step``:
    called with each new metrics row (after the step's checkpoint, if any).
    """

    dir: str | Path | None = None
    resume: bool = False
    progress: bool = False
    desc: str = "self-improvement"
    on_step: Callable[[dict], None] | None = None

    def __post_init__(self) -> None:
        for name in ("resume", "progress"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"Run.{name} must be true or false, got {getattr(self, name)!r}")
        if self.resume and self.dir is None:
            raise ValueError("Run(resume=True) needs a dir")

    @classmethod
    def of(cls, run) -> Run:
        """``run`` as a :class:`Run`: a Run, a folder (``str`` / ``Path``) or ``None``."""
        if isinstance(run, Run):
            return run
        if run is None or isinstance(run, (str, Path)):
            return cls(dir=run)
        raise TypeError(f"run must be a Run, a folder or None, got {run!r}")
