"""Optimisers over ProMP weight distributions, sharing one ask / tell contract: PRO, RWR, RWPO,
and the peers users would pick instead, CEM and CMA-ES (pycma, wrapped; needs the peers extra)."""

from .base import BaseOptimizer, OptimizeResult
from .cem import CEM
from .cmaes import CMAES
from .efficient_pro import EPRO
from .functional import noise_floor_threshold, pearson_relevance, pro_update, stable_rewards
from .pro import PRO
from .rwpo import RWPO, rwpo_relevance_basis
from .rwr import RWR

OPTIMIZERS = {"pro": PRO, "rwr": RWR, "rwpo": RWPO, "cem": CEM, "cmaes": CMAES, "epro": EPRO}

__all__ = [
    "BaseOptimizer", "OptimizeResult", "PRO", "RWR", "RWPO", "CEM", "CMAES", "EPRO", "OPTIMIZERS",
    "pearson_relevance", "pro_update", "stable_rewards", "noise_floor_threshold", "rwpo_relevance_basis",
]
