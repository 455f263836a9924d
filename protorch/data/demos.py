"""Loading demonstrations stored in the authors' point-particle format.

A folder holds pairs ``trajK.out`` / ``envK.out`` (``K = 0, 1, ...``): the trajectory is a CSV
without header, one ``x,y`` row per mouse sample; the environment is 6 numbers, one per line,
``start_x start_y wall_x hole_y goal_x goal_y`` (the authors' public repository marcoewerton/avoid_moving_walls).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import torch
from torch import Tensor

__all__ = ["load_human_demos", "WORKSPACE", "ENV_NAMES"]

_NAME = re.compile(r"^(traj|env)(\d+)\.out$")
# the point-particle task's workspace, both axes (protorch.tasks.point_particle.WORKSPACE; a test
# keeps the two equal): every sample and every environment coordinate lies in it
WORKSPACE = (0.0, 10.0)
ENV_NAMES = ("start_x", "start_y", "wall_x", "hole_y", "goal_x", "goal_y")


def _read_text(path: Path) -> str:
    try:
        return path.read_text()
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path} is not a text file (byte {exc.start} cannot be decoded: {exc.reason})") from None


def _env_names(i: int) -> list[str]:
    return [ENV_NAMES[i] if i < len(ENV_NAMES) else f"value {i + 1}"]


def _check_workspace(values: list[float], path: Path, lineno: int, names: list[str]) -> None:
    lo, hi = WORKSPACE
    for v, name in zip(values, names):
        if not lo <= v <= hi:
            raise ValueError(f"{path}:{lineno}: {name} = {v:g} lies outside the workspace [{lo:g}, {hi:g}]")


def _parse_floats(text: str, path: Path, per_row: int, names=None) -> list[list[float]]:
    """Rows of ``per_row`` comma-separated finite floats inside the workspace; blank lines are
    skipped. ``names(row_index)`` names a row's values in the error messages."""
    rows = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        fields = line.split(",")
        if len(fields) != per_row:
            raise ValueError(f"{path}:{lineno}: expected {per_row} value(s), got {len(fields)}: {line!r}")
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise ValueError(f"{path}:{lineno}: not a number: {line!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"{path}:{lineno}: NaN or infinite value: {line!r}")
        _check_workspace(values, path, lineno, names(len(rows)) if names else ["value"] * per_row)
        rows.append(values)
    return rows


def load_human_demos(
    folder: str | Path, *, dtype: torch.dtype = torch.float64
) -> tuple[list[Tensor], Tensor]:
    """Read every ``trajK.out`` / ``envK.out`` pair of ``folder``, in increasing ``K``.

    Returns ``(demos, envs)``: a list of ``n`` tensors ``(T_i, 2)`` and ``envs (n, 6)``, row
    ``i`` the environment of ``demos[i]``. Other files (a README) are ignored.

    Raises:
        FileNotFoundError: ``folder`` does not exist or is not a directory.
        ValueError: no pairs, a trajectory without its environment file or the reverse, a file
            that is not text, a row that is not two numbers, an environment that is not 6
            numbers, a NaN or infinite value, a sample or environment coordinate outside the
            workspace ``[0, 10]``, or a trajectory of fewer than 2 samples. The message names the
            file and line (and the value and bound).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"demonstration folder {folder} does not exist or is not a directory")
    found: dict[str, dict[int, Path]] = {"traj": {}, "env": {}}
    for path in folder.iterdir():
        m = _NAME.match(path.name)
        if m and path.is_file():
            found[m.group(1)][int(m.group(2))] = path
    trajs, envs = found["traj"], found["env"]
    if not trajs and not envs:
        raise ValueError(f"{folder} holds no trajK.out / envK.out files")
    missing_env, missing_traj = sorted(trajs.keys() - envs.keys()), sorted(envs.keys() - trajs.keys())
    if missing_env or missing_traj:
        parts = []
        if missing_env:
            parts.append(f"traj files without env file for K = {missing_env}")
        if missing_traj:
            parts.append(f"env files without traj file for K = {missing_traj}")
        raise ValueError(f"unpaired demonstration files in {folder}: " + "; ".join(parts))
    demos, env_rows = [], []
    for k in sorted(trajs):
        rows = _parse_floats(_read_text(trajs[k]), trajs[k], 2, lambda _: ["x", "y"])
        if len(rows) < 2:
            raise ValueError(f"{trajs[k]}: a trajectory needs at least 2 samples, got {len(rows)}")
        env = [v for (v,) in _parse_floats(_read_text(envs[k]), envs[k], 1, _env_names)]
        if len(env) != 6:
            raise ValueError(
                f"{envs[k]}: expected 6 numbers (start_x start_y wall_x hole_y goal_x goal_y), got {len(env)}"
            )
        demos.append(torch.tensor(rows, dtype=dtype))  # (T_k, 2)
        env_rows.append(env)
    return demos, torch.tensor(env_rows, dtype=dtype)  # list of (T_k, 2), (n, 6)
