"""Side switches of the arm's online test measured geometrically, for any map.

:attr:`protorch.control.arm.ArmEpisodeResult.switches` counts changes of the tracked *label*;
a map without labels (the paper's single map) has one label and can never register a switch,
even when its mean swings from one side of the can to the other as the can moves. Here the side
is read off the geometry instead: at every instant ``t`` the mean trajectory the arm tracks
(``result.weights[:, t]``, the map's answer for the environment of that instant) is turned into
its end-effector path and the task's homotopy test
(:meth:`~protorch.tasks.ArmReachTask.side_of_path`,
the signed angle the path sweeps around the can of that instant) says which side it passes.
A geometric switch is a change of that side between consecutive instants.

The whole mean (phase 0 to 1) is classified, not only what is left of it: a side is a property
of a path that goes around the can, and the part still ahead after the arm has passed the can
does not go around it. The path is evaluated at the task's cost steps (25 of 100 by default).
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["geometric_sides", "count_changes", "geometric_switch_summary"]


def geometric_sides(result, task, *, chunk: int = 4096) -> Tensor:
    """``(E, T+1)`` long: the side (``LEFT`` 0 / ``RIGHT`` 1) of the tracked mean at each instant.

    ``result``: an :class:`~protorch.control.arm.ArmEpisodeResult` run with ``record=True``
    (it needs ``weights`` and ``promp``); ``task``: the :class:`~protorch.tasks.ArmReachTask`."""
    if result.weights is None or result.promp is None:
        raise ValueError(
            "geometric_sides needs an episode result run with record=True (weights and promp)"
        )
    w, envs = result.weights, result.envs  # (E, T+1, N), (E, T+1, 4)
    if w.shape[:2] != envs.shape[:2]:
        raise ValueError(
            f"weights {tuple(w.shape)} and envs {tuple(envs.shape)} disagree on (E, T+1)"
        )
    promp = result.promp
    idx = task.cost_indices(promp.num_steps).to(w.device)  # (T',)
    flat_w, flat_e = (
        w.reshape(-1, w.shape[-1]),
        envs.reshape(-1, envs.shape[-1]),
    )  # (E (T+1), N), (E (T+1), 4)
    sides = []
    with torch.no_grad():
        for a in range(0, flat_w.shape[0], chunk):
            traj = promp.trajectory(flat_w[a : a + chunk])[:, idx]  # (c, T', J)
            path = task.ee_path(traj)  # (c, T', 3)
            sides.append(task.side_of_path(path.to(flat_e.dtype), flat_e[a : a + chunk]))  # (c,)
    return torch.cat(sides).reshape(envs.shape[:2])


def count_changes(sides: Tensor) -> Tensor:
    """Changes between consecutive instants: ``(E, T+1) -> (E,)`` long."""
    return (sides[:, 1:] != sides[:, :-1]).sum(-1)


def geometric_switch_summary(result, task) -> dict:
    """JSON-able: ``switches_geometric`` (total), ``episodes_with_geometric_switch`` and the
    success rate among those episodes."""
    if result is None:
        return {"switches_geometric": 0, "episodes_with_geometric_switch": 0}
    sw = count_changes(geometric_sides(result, task))  # (E,)
    switched = sw > 0
    rate = float(result.success[switched].double().mean()) if bool(switched.any()) else float("nan")
    return {
        "switches_geometric": int(sw.sum()),
        "episodes_with_geometric_switch": int(switched.sum()),
        "success_rate_with_geometric_switch": rate,
    }
