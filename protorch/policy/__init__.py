"""The shipped policy: a trained run in a control loop (``protorch.load(run)``).

* :mod:`~protorch.policy.policy`: :class:`Policy` and :class:`Reference` (the class choice, the
  reference, continuity, ``planner="inline"`` or ``"thread"``);
* :mod:`~protorch.policy.two_rate`: the planner thread and the tracker;
* :mod:`~protorch.policy.process_planner`: the planner in a child process (``planner="process"``);
* :mod:`~protorch.policy.programs`: both halves as programs (``export(folder)``);
* :mod:`~protorch.policy.limits`: the robot's velocity, acceleration and jerk limits (Ruckig);
* :mod:`~protorch.policy.means`: every class's mean at an environment, the basis;
* :mod:`~protorch.policy.export`: the per-call computation for ``torch.export``;
* :mod:`~protorch.policy.settings`: a run's class-choice settings;
* :mod:`~protorch.policy.load`: a run folder as a policy, without Hydra or OmegaConf.
"""

from .load import load_policy
from .policy import DEFAULT_BLEND, Policy, Reference

__all__ = ["DEFAULT_BLEND", "Policy", "Reference", "load_policy"]
