"""protorch: improving demonstrated trajectory distributions with PRO (Ewerton et al., IROS 2019).

Core pieces: :class:`ProMP` (demonstrations -> Gaussian over basis weights), the functional PRO
core (:func:`pearson_relevance`, :func:`pro_update`) and the optimisers :class:`PRO`,
:class:`EPRO`, :class:`RWR`, :class:`RWPO`, :class:`CEM` and :class:`CMAES` sharing one ask /
tell contract (:data:`OPTIMIZERS` by name); :class:`ProtorchError`, the base of protorch's errors;
the environment -> ProMP map
(:func:`make_env_map`, :class:`TrajectoryDataset`, :func:`load`); the self-improvement loop
(:func:`self_improve` with :class:`LoopSettings`, :class:`OptimizerSpec` and :class:`Run`).
"""

from .data.checkpoint import save_model
from .data.dataset import TrajectoryDataset
from .data.files import CheckpointError
from .errors import ProtorchError
from .gp import load_env_map, make_env_map
from .gp.model import EnvToProMP
from .loop import LoopResult, LoopSettings, OptimizerSpec, Run, demonstration_dataset, self_improve
from .optim import (
    CEM,
    CMAES,
    EPRO,
    OPTIMIZERS,
    PRO,
    RWPO,
    RWR,
    BaseOptimizer,
    OptimizeResult,
    pearson_relevance,
    pro_update,
    stable_rewards,
)
from .policy import Policy, Reference
from .policy.load import load_policy
from .primitives.promp import ProMP

__version__ = "0.1.0"


def load(
    run, *, device=None, dtype=None, backend: str | None = None, warm_up: bool = True, **options
) -> Policy:
    """A trained run as a :class:`Policy` (an :class:`EnvToProMP` that also gives references for a
    control loop): ``run`` is a run folder (its ``config.yaml`` rebuilds the task through the
    experiment's own builder), its ``checkpoint`` folder or the ``.safetensors`` file (the map
    alone); ``planner="thread"`` for a control loop (the class choice on a thread beside it).
    Imports neither Hydra nor OmegaConf. See :func:`protorch.policy.load.load_policy`."""
    return load_policy(run, device=device, dtype=dtype, backend=backend, warm_up=warm_up, **options)


__all__ = [
    "ProMP",
    "PRO",
    "EPRO",
    "RWR",
    "RWPO",
    "CEM",
    "CMAES",
    "OPTIMIZERS",
    "BaseOptimizer",
    "OptimizeResult",
    "ProtorchError",
    "pearson_relevance",
    "pro_update",
    "stable_rewards",
    "TrajectoryDataset",
    "make_env_map",
    "load_env_map",
    "EnvToProMP",
    "Policy",
    "Reference",
    "CheckpointError",
    "load",
    "save_model",
    "self_improve",
    "LoopSettings",
    "OptimizerSpec",
    "Run",
    "LoopResult",
    "demonstration_dataset",
    "__version__",
]
