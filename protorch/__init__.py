"""protorch: improving demonstrated trajectory distributions with PRO (Ewerton et al., IROS 2019).

Core pieces: :class:`ProMP` (demonstrations -> Gaussian over basis weights), the functional PRO
core (:func:`pearson_relevance`, :func:`pro_update`) and the optimisers :class:`PRO`,
:class:`RWR` and :class:`RWPO` sharing one ask / tell contract.
"""

from .optim import (
    PRO,
    RWPO,
    RWR,
    BaseOptimizer,
    OptimizeResult,
    pearson_relevance,
    pro_update,
    stable_rewards,
)
from .promp import ProMP

__version__ = "0.1.0"

__all__ = [
    "ProMP", "PRO", "RWR", "RWPO", "BaseOptimizer", "OptimizeResult",
    "pearson_relevance", "pro_update", "stable_rewards", "__version__",
]
