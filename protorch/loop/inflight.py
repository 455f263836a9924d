"""What a refill loop has in flight at a checkpoint, saved beside it so that a resumed run goes on
bit for bit as the uninterrupted run does.

The refill loop (:mod:`.refill`) keeps ``B`` environments in the rows of one long-lived optimiser;
at a checkpoint most of them are half optimised. Restarting them from the map on resume would
change which environments share the optimiser's batch and the random numbers each one gets, and
with them every later number. So the checkpoint keeps the in-flight state:

* the optimiser (:func:`optimizer_state`): its buffers (mean, var, beta, converged), its public
  tensors and lists of tensors (``age``, ``rollouts``, ``relevance``, the history its
  convergence rule reads), its numbers (``iteration``, ``num_objectives``, ...) and its
  generator's state as drawing in order leaves it
  (:meth:`~protorch.optim.draws.NormalDraws.get_state`);
* the slots (which pool index each holds, its environment, the start's success, when each row
  stopped), the environments started so far and the slots waiting for their next environment.

It is written to ``<run_dir>/checkpoint/inflight-<step>.safetensors`` (atomic, no pickle) before
the data set's checkpoint, whose loop state names that file and its tensor checksum: a run killed
between the two writes resumes from the previous checkpoint and its own file, which is removed
only after the new data set is published. A checkpoint of a refill loop that names no such file
(an older protorch's) resumes by restarting the problems in flight from the map, with a warning.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from torch import Tensor

from ..data.files import (
    CheckpointError,
    atomic_write_safetensors,
    read_safetensors,
    tensor_checksum,
)

__all__ = [
    "INFLIGHT_FORMAT",
    "INFLIGHT_SCHEMA",
    "inflight_name",
    "load_optimizer_state",
    "optimizer_state",
    "read_inflight",
    "remove_inflight",
    "write_inflight",
]

INFLIGHT_FORMAT = "protorch.loop_inflight"
INFLIGHT_SCHEMA = 1
# what an optimiser rebuilds itself (its generator is saved by its state; the rule is stateless)
_SKIP = frozenset({"training", "generator", "draws", "convergence", "asked_objective"})


def inflight_name(step: int) -> str:
    """The in-flight file of the checkpoint after step ``step``."""
    return f"inflight-{int(step)}.safetensors"


def _number(x, where: str):
    """``x`` (None, bool, int, str or a finite float) as the JSON of the file holds it."""
    if x is None or isinstance(x, (bool, int, str)):
        return x
    if isinstance(x, float) and math.isfinite(x):
        return x
    raise TypeError(f"the refill loop cannot save the optimiser's {where}={x!r} in a checkpoint")


def optimizer_state(opt) -> tuple[dict[str, Tensor], dict]:
    """``(tensors, meta)`` of a batched optimiser between two iterations: its buffers
    (``buffer.<name>``), public tensors (``tensor.<name>``), lists of tensors
    (``list.<name>.<i>``), dicts of lists of tensors (``dict.<name>.<key>.<i>``), its numbers and
    lists of numbers (``meta``) and its generator's state (``generator``). ``TypeError`` names an
    attribute of another kind (an optimiser the loop cannot checkpoint in flight)."""
    if getattr(opt, "_asked", None) is not None or getattr(opt, "_next", None) is not None:
        raise RuntimeError("the optimiser's state can only be saved between two iterations")
    tensors: dict[str, Tensor] = {f"buffer.{k}": v for k, v in opt.named_buffers()}
    tensors["generator"] = opt.draws.get_state()
    numbers: dict = {}
    lists: dict[str, int] = {}
    dicts: dict[str, dict[str, int]] = {}
    buffers = {k for k, _ in opt.named_buffers()}
    for name, v in vars(opt).items():
        if name.startswith("_") or name in _SKIP or name in buffers:
            continue
        where = f"{type(opt).__name__}.{name}"
        if isinstance(v, Tensor):
            tensors[f"tensor.{name}"] = v
        elif isinstance(v, list) and v and all(isinstance(x, Tensor) for x in v):
            lists[name] = len(v)
            tensors.update({f"list.{name}.{i}": x for i, x in enumerate(v)})
        elif isinstance(v, list):
            numbers[name] = [_number(x, where) for x in v]
        elif isinstance(v, dict) and all(
            isinstance(x, list) and all(isinstance(t, Tensor) for t in x) for x in v.values()
        ):
            dicts[name] = {str(k): len(x) for k, x in v.items()}
            for k, x in v.items():
                tensors.update({f"dict.{name}.{k}.{i}": t for i, t in enumerate(x)})
        else:
            numbers[name] = _number(v, where)
    meta = {"class": type(opt).__name__, "numbers": numbers, "lists": lists, "dicts": dicts}
    return tensors, meta


def load_optimizer_state(opt, tensors: dict[str, Tensor], meta: dict) -> None:
    """Put the state :func:`optimizer_state` took back into ``opt``, a new optimiser of the same
    class and size built with the same keyword arguments."""
    if meta["class"] != type(opt).__name__:
        raise CheckpointError(
            f"the checkpoint's optimiser in flight is a {meta['class']}, this run's a "
            f"{type(opt).__name__}"
        )
    device = opt.mean.device

    def here(saved: Tensor, like=None) -> Tensor:
        """``saved`` on the device of the tensor it replaces (the optimiser's for a new one)."""
        return saved.to(like.device if isinstance(like, Tensor) else device)

    for name, buf in opt.named_buffers():
        saved = tensors[f"buffer.{name}"]
        if saved.shape != buf.shape or saved.dtype != buf.dtype:
            raise CheckpointError(
                f"the checkpoint's optimiser in flight has {name} {tuple(saved.shape)} "
                f"{saved.dtype}, this run's {tuple(buf.shape)} {buf.dtype}"
            )
        buf.copy_(saved)
    for name, v in meta["numbers"].items():
        setattr(opt, name, v)
    for key, t in tensors.items():
        if key.startswith("tensor."):
            name = key.removeprefix("tensor.")
            setattr(opt, name, here(t, getattr(opt, name, None)))
    for name, n in meta["lists"].items():
        setattr(opt, name, [here(tensors[f"list.{name}.{i}"]) for i in range(n)])
    for name, keys in meta["dicts"].items():
        setattr(
            opt,
            name,
            {k: [here(tensors[f"dict.{name}.{k}.{i}"]) for i in range(n)] for k, n in keys.items()},
        )
    opt.draws.set_state(tensors["generator"])


def write_inflight(folder: Path, step: int, tensors: dict[str, Tensor], meta: dict) -> dict:
    """Write the in-flight state of the checkpoint after ``step`` into ``folder`` (atomic); return
    the record the data set's loop state keeps (``file``, ``checksum``)."""
    path = folder / inflight_name(step)
    body = {"format": INFLIGHT_FORMAT, "schema_version": INFLIGHT_SCHEMA, "state": meta}
    cpu = {k: v.detach().to("cpu").contiguous() for k, v in tensors.items()}
    atomic_write_safetensors(path, cpu, body)
    return {"file": path.name, "checksum": tensor_checksum(cpu), "keys": sorted(cpu)}


def read_inflight(folder: Path, record: dict) -> tuple[dict[str, Tensor], dict]:
    """The ``(tensors, meta)`` of the in-flight file a checkpoint's loop state names (``record``);
    :class:`~protorch.data.files.CheckpointError` if it is missing or is not that file."""
    name = str(record["file"])
    if re.fullmatch(r"inflight-\d+\.safetensors", name) is None:
        raise CheckpointError(
            f"{folder / 'dataset.safetensors'} names {name!r} as its in-flight file, not an "
            "inflight-<step>.safetensors beside it"
        )
    path = folder / name
    if not path.is_file():
        raise CheckpointError(
            f"{path} is missing: the checkpoint's loop has environments in flight whose state it "
            "holds; without it the run cannot resume as it would have gone on"
        )
    tensors, body = read_safetensors(
        path, fmt=INFLIGHT_FORMAT, schema_version=INFLIGHT_SCHEMA, keys=record["keys"]
    )
    if body["checksum"] != record["checksum"]:
        raise CheckpointError(
            f"{path} is not the in-flight state of {folder / 'dataset.safetensors'} (another "
            "checkpoint's): its checksum differs"
        )
    return tensors, body["state"]


def remove_inflight(folder: Path, keep: str | None) -> None:
    """Delete the in-flight files in ``folder`` except ``keep`` (the current checkpoint's)."""
    for path in folder.glob("inflight-*.safetensors"):
        if path.name != keep:
            path.unlink(missing_ok=True)
