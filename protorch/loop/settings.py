"""The loop's own settings (:class:`LoopSettings`), validated once, before any work."""

from __future__ import annotations

from dataclasses import dataclass

from ..checks import check_int

__all__ = ["ADD_ONLY", "CHOICES", "LoopSettings"]

ADD_ONLY = ("converged", "success", "all")
CHOICES = ("random", "nearest", "dataset")


@dataclass(frozen=True)
class LoopSettings:
    """The settings of :func:`~protorch.loop.self_improve` that fix which environments are tried,
    how many at once, and which solutions are kept (see its docstring for each one).

    Construction validates them (a clear ``ValueError`` naming the setting) and stores the
    integers as ``int``.
    """

    num_envs: int
    batch_size: int = 1
    add_only: str = "success"
    choice: str = "random"
    each_label: bool = False
    sample_steps: int | None = None
    seed: int = 0
    min_var: float = 0.0
    var_floor: float = 0.0
    checkpoint_every: int = 1
    refill: bool = False
    refill_group: int = 1

    def __post_init__(self) -> None:
        if not isinstance(self.refill, bool):
            raise ValueError(f"refill must be true or false, got {self.refill!r}")
        for name, lo in (
            ("num_envs", 0),
            ("batch_size", 1),
            ("checkpoint_every", 1),
            ("refill_group", 1),
        ):
            object.__setattr__(self, name, check_int(getattr(self, name), name, lo))
        if self.add_only not in ADD_ONLY:
            raise ValueError(f"add_only must be one of {ADD_ONLY}, got {self.add_only!r}")
        if self.choice not in CHOICES:
            raise ValueError(f"choice must be one of {CHOICES}, got {self.choice!r}")
        for name in ("min_var", "var_floor"):
            if not float(getattr(self, name)) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        s = self.sample_steps
        if s is not None and (isinstance(s, bool) or int(s) != s or int(s) < 2):
            raise ValueError(f"sample_steps must be None or an int >= 2, got {s!r}")

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
