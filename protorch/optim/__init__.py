"""Optimisers over ProMP weight distributions, sharing one ask / tell contract."""

from .base import BaseOptimizer, OptimizeResult
from .functional import noise_floor_threshold, pearson_relevance, pro_update, stable_rewards
from .pro import PRO
from .rwpo import RWPO, rwpo_relevance_basis
from .rwr import RWR

OPTIMIZERS = {"pro": PRO, "rwr": RWR, "rwpo": RWPO}

__all__ = [
    "BaseOptimizer", "OptimizeResult", "PRO", "RWR", "RWPO", "OPTIMIZERS",
    "pearson_relevance", "pro_update", "stable_rewards", "noise_floor_threshold", "rwpo_relevance_basis",
]
