"""Optimisers over ProMP weight distributions, sharing one ask / tell contract: PRO, RWR, RWPO,
and the peers users would pick instead, CEM and CMA-ES (pycma, wrapped; needs the peers extra).

:data:`OPTIMIZERS` maps a name (the Hydra group ``conf/optimizer/<name>.yaml``) to its class;
:func:`optimizer_class` and :func:`make_optimizer` build from a name, so a registered optimiser is
reachable from the command line (``optimizer=<name>``) and from the contract tests.
"""

from torch import Tensor

from .base import BaseOptimizer, OptimizeResult
from .cem import CEM
from .cmaes import CMAES
from .efficient_pro import EPRO
from .functional import noise_floor_threshold, pearson_relevance, pro_update, stable_rewards
from .pro import PRO
from .rwpo import RWPO, rwpo_relevance_basis
from .rwr import RWR

OPTIMIZERS: dict[str, type[BaseOptimizer]] = {
    "pro": PRO,
    "rwr": RWR,
    "rwpo": RWPO,
    "cem": CEM,
    "cmaes": CMAES,
    "epro": EPRO,
}

__all__ = [
    "BaseOptimizer",
    "OptimizeResult",
    "PRO",
    "RWR",
    "RWPO",
    "CEM",
    "CMAES",
    "EPRO",
    "OPTIMIZERS",
    "optimizer_class",
    "make_optimizer",
    "pearson_relevance",
    "pro_update",
    "stable_rewards",
    "noise_floor_threshold",
    "rwpo_relevance_basis",
]


def optimizer_class(name: str) -> type[BaseOptimizer]:
    """The registered optimiser class called ``name`` (a key of :data:`OPTIMIZERS`)."""
    if name not in OPTIMIZERS:
        raise ValueError(f"unknown optimizer {name!r}; choose one of {sorted(OPTIMIZERS)}")
    return OPTIMIZERS[name]


def make_optimizer(name: str, mean: Tensor, var: Tensor, **kwargs) -> BaseOptimizer:
    """``OPTIMIZERS[name](mean (N,) or (B, N), var, **kwargs)``."""
    return optimizer_class(name)(mean, var, **kwargs)
