"""Demonstration folders in the authors' point-particle format, for any task.

A folder holds pairs ``trajK.out`` / ``envK.out`` (``K = 0, 1, ...``): the trajectory is a CSV
without header, one row of ``D`` comma-separated numbers per sample (the point particle: ``x,y``
per mouse sample; the arm: the 7 joint angles in radians); the environment is ``E`` numbers, one
per line (the point particle: ``start_x start_y wall_x hole_y goal_x goal_y``, as in the authors'
public repository marcoewerton/avoid_moving_walls; the arm: ``can_x can_y goal_x goal_y``).
Demonstrations whose environment files hold the same numbers form one environment.

:func:`read_demos` reads and checks a folder against a :class:`DemoFormat` (column names, bounds);
:func:`load_human_demos` is the point particle's; :func:`write_demo` writes one pair atomically,
numbers as ``%.18e`` (what ``numpy.savetxt`` writes, exact for float64); :func:`check_demo_groups`
refuses an environment (and label) with too few demonstrations, naming its files. Other files in
a folder (a README, the teach page's ``teach.json``, :func:`read_marks`) are ignored by the reader.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Sequence

import torch
from torch import Tensor

from .files import atomic_write_bytes
from .formats import DemoFolder, DemoFormat
from .recordings import is_recordings_folder, read_recordings

__all__ = [
    "DemoFormat",
    "DemoFolder",
    "PARTICLE_FORMAT",
    "WORKSPACE",
    "ENV_NAMES",
    "MARKS_FILE",
    "LONE_RULE",
    "accept_demo_folder",
    "check_demo_groups",
    "demo_files",
    "load_human_demos",
    "read_demo_folder",
    "read_demos",
    "read_marks",
    "write_demo",
]

_NAME = re.compile(r"^(traj|env)(\d+)\.out$")
# the point-particle task's workspace, both axes (protorch.tasks.point_particle.WORKSPACE; a test
# keeps the two equal): every sample and every environment coordinate lies in it
WORKSPACE = (0.0, 10.0)
ENV_NAMES = ("start_x", "start_y", "wall_x", "hole_y", "goal_x", "goal_y")
MARKS_FILE = "teach.json"  # written by the teach page (protorch.view.teach): quality marks per K


PARTICLE_FORMAT = DemoFormat(
    ("x", "y"), ENV_NAMES, (WORKSPACE,) * 2, (WORKSPACE,) * 6, "the workspace", "the workspace"
)


def _read_text(path: Path) -> str:
    try:
        return path.read_text()
    except UnicodeDecodeError as exc:
        raise ValueError(
            f"{path} is not a text file (byte {exc.start} cannot be decoded: {exc.reason})"
        ) from None


def _parse_floats(
    text: str, path: Path, per_row: int, names, bounds, bound_name: str
) -> list[list[float]]:
    """Rows of ``per_row`` comma-separated finite floats within ``bounds``; blank lines are
    skipped. ``names(row_index)`` / ``bounds(row_index)`` name and bound a row's values."""
    rows: list[list[float]] = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        fields = line.split(",")
        if len(fields) != per_row:
            raise ValueError(
                f"{path}:{lineno}: expected {per_row} value(s), got {len(fields)}: {line!r}"
            )
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise ValueError(f"{path}:{lineno}: not a number: {line!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"{path}:{lineno}: NaN or infinite value: {line!r}")
        for v, name, bound in zip(values, names(len(rows)), bounds(len(rows))):
            if bound is not None and not bound[0] <= v <= bound[1]:
                raise ValueError(
                    f"{path}:{lineno}: {name} = {v:g} lies outside {bound_name} "
                    f"[{bound[0]:g}, {bound[1]:g}]"
                )
        rows.append(values)
    return rows


def demo_files(folder: str | Path) -> tuple[dict[int, Path], dict[int, Path]]:
    """``(traj files, env files)`` of ``folder``, each ``{K: path}`` (no pairing checked)."""
    found: dict[str, dict[int, Path]] = {"traj": {}, "env": {}}
    for path in Path(folder).iterdir():
        m = _NAME.match(path.name)
        if m and path.is_file():
            found[m.group(1)][int(m.group(2))] = path
    return found["traj"], found["env"]


def _pairs(folder: Path) -> tuple[dict[int, Path], dict[int, Path]]:
    if not folder.is_dir():
        raise FileNotFoundError(
            f"demonstration folder {folder} does not exist or is not a directory"
        )
    trajs, envs = demo_files(folder)
    if not trajs and not envs:
        raise ValueError(f"{folder} holds no trajK.out / envK.out files")
    missing_env, missing_traj = (
        sorted(trajs.keys() - envs.keys()),
        sorted(envs.keys() - trajs.keys()),
    )
    if missing_env or missing_traj:
        parts = []
        if missing_env:
            parts.append(f"traj files without env file for K = {missing_env}")
        if missing_traj:
            parts.append(f"env files without traj file for K = {missing_traj}")
        raise ValueError(f"unpaired demonstration files in {folder}: " + "; ".join(parts))
    return trajs, envs


def read_demos(
    folder: str | Path, fmt: DemoFormat, *, dtype: torch.dtype = torch.float64
) -> DemoFolder:
    """Read every ``trajK.out`` / ``envK.out`` pair of ``folder`` in increasing ``K``, checked
    against ``fmt``.

    Raises:
        FileNotFoundError: ``folder`` does not exist or is not a directory.
        ValueError: no pairs, a trajectory without its environment file or the reverse, a file
            that is not text, a row with the wrong number of values, an environment with the
            wrong number of values, a NaN or infinite value, a value outside its bounds, or a
            trajectory of fewer than 2 samples. The message names the file and line (and the
            value and bound).
    """
    folder = Path(folder)
    trajs, envs = _pairs(folder)
    d, e = len(fmt.columns), len(fmt.env_names)
    col_bounds = (lambda _: fmt.column_bounds) if fmt.column_bounds else (lambda _: [None] * d)
    env_name = lambda i: [fmt.env_names[i] if i < e else f"value {i + 1}"]
    env_bound = lambda i: [fmt.env_bounds[i] if fmt.env_bounds and i < e else None]
    out = DemoFolder([], torch.zeros(0, e, dtype=dtype))
    rows_env = []
    for k in sorted(trajs):
        rows = _parse_floats(
            _read_text(trajs[k]),
            trajs[k],
            d,
            lambda _: fmt.columns,
            col_bounds,
            fmt.column_bound_name,
        )
        if len(rows) < 2:
            raise ValueError(f"{trajs[k]}: a trajectory needs at least 2 samples, got {len(rows)}")
        env = [
            v
            for (v,) in _parse_floats(
                _read_text(envs[k]), envs[k], 1, env_name, env_bound, fmt.env_bound_name
            )
        ]
        if len(env) != e:
            raise ValueError(
                f"{envs[k]}: expected {e} numbers ({' '.join(fmt.env_names)}), got {len(env)}"
            )
        out.demos.append(torch.tensor(rows, dtype=dtype))  # (T_k, D)
        out.files.append((trajs[k], envs[k]))
        out.indices.append(k)
        rows_env.append(env)
    out.envs = torch.tensor(rows_env, dtype=dtype).reshape(-1, e)  # (n, E)
    return out


def read_demo_folder(
    folder: str | Path,
    fmt: DemoFormat,
    cleaning=None,
    *,
    labeller=None,
    dtype: torch.dtype = torch.float64,
) -> tuple[DemoFolder, Tensor | None]:
    """Either format: a folder of timestamped ``*.csv`` recordings
    (:func:`protorch.data.recordings.read_recordings`, cleaned by ``cleaning``, labelled by
    ``labeller``) or of the authors' ``trajK.out`` / ``envK.out`` pairs (:func:`read_demos`,
    read as they are, labels ``None``). A folder holding both is refused."""
    folder = Path(folder)
    if is_recordings_folder(folder):
        if any(demo_files(folder)):
            raise ValueError(
                f"{folder} holds both *.csv recordings and trajK.out / envK.out files: keep one "
                "format "
                "per folder"
            )
        return read_recordings(folder, fmt, cleaning, labeller=labeller, dtype=dtype)
    return read_demos(folder, fmt, dtype=dtype), None


def load_human_demos(
    folder: str | Path, *, dtype: torch.dtype = torch.float64, cleaning=None
) -> tuple[list[Tensor], Tensor]:
    """The point particle's folder (:data:`PARTICLE_FORMAT`: ``x,y`` rows, 6 environment numbers,
    everything inside the workspace ``[0, 10]``), either format (:func:`read_demo_folder`):
    ``(demos, envs)``, a list of ``n`` tensors ``(T_i, 2)`` and ``envs (n, 6)``. Errors as
    :func:`read_demos` / :func:`~protorch.data.recordings.read_recordings`."""
    out, _ = read_demo_folder(folder, PARTICLE_FORMAT, cleaning, dtype=dtype)
    return out.demos, out.envs  # list of (T_k, 2), (n, 6)


def _number(v: float) -> str:
    return f"{float(v):.18e}"


def write_demo(folder: str | Path, k: int, traj, env) -> tuple[Path, Path]:
    """Write demonstration ``K = k``: ``trajK.out`` (``traj (T, D)``, one comma-separated row
    per sample) and ``envK.out`` (``env (E,)``, one number per line), each atomically (temporary
    file, fsync, rename). The environment file is written first, so an interrupted write leaves at
    most an ``envK.out`` without its trajectory, never a trajectory without its environment.
    Returns ``(traj path, env path)``."""
    traj = torch.as_tensor(traj, dtype=torch.float64).detach().cpu()
    env = torch.as_tensor(env, dtype=torch.float64).detach().cpu()
    if traj.ndim != 2 or traj.shape[0] < 2 or env.ndim != 1:
        raise ValueError(
            f"write_demo needs traj (T >= 2, D) and env (E,), got {tuple(traj.shape)} and "
            f"{tuple(env.shape)}"
        )
    if not (bool(torch.isfinite(traj).all()) and bool(torch.isfinite(env).all())):
        raise ValueError("write_demo: traj and env must be finite")
    if int(k) < 0:
        raise ValueError(f"write_demo: k must be >= 0, got {k}")
    folder = Path(folder)
    env_text = "".join(_number(v) + "\n" for v in env.tolist())
    env_path = atomic_write_bytes(folder / f"env{int(k)}.out", env_text.encode())
    text = "".join(",".join(map(_number, row)) + "\n" for row in traj.tolist())
    traj_path = atomic_write_bytes(folder / f"traj{int(k)}.out", text.encode())
    return traj_path, env_path


def check_demo_groups(
    envs: Tensor,
    files: Sequence[tuple[Path, Path]],
    labels: Tensor | None = None,
    *,
    minimum: int = 2,
    label_names: dict | None = None,
    lone: str = "refuse",
    excluded: Sequence[dict] | None = None,
) -> dict:
    """Refuse an environment (with ``labels``: an environment and label) holding fewer than
    ``minimum`` demonstrations (a weight variance needs 2), naming its files.

    ``lone="pool"``: such an entry is kept and takes its weight variance from the rule of
    :func:`protorch.loop.initial.demonstration_dataset` (the mean variance of the same label's
    entries with ``minimum`` or more demonstrations); refused only where that label has no such
    entry anywhere. ``excluded``: the folder's excluded recordings (``{file, reason}``), named in
    the refusal. Returns ``{"rule", "lone": [{"files", "label", "side"}]}``."""
    if lone not in ("refuse", "pool"):
        raise ValueError(f"lone must be 'refuse' or 'pool', got {lone!r}")
    keyed = envs.to(torch.float64)
    if labels is not None:
        keyed = torch.cat([keyed, torch.as_tensor(labels).to(torch.float64).reshape(-1, 1)], 1)
    _, group, counts = torch.unique(keyed, dim=0, return_inverse=True, return_counts=True)
    lab = (
        torch.zeros(len(files), dtype=torch.long)
        if labels is None
        else torch.as_tensor(labels).reshape(-1)
    )
    name = lambda i: (label_names or {}).get(int(lab[i]), int(lab[i]))
    pooled_from = {int(lab[i]) for i in range(len(files)) if int(counts[group[i]]) >= minimum}
    gone = (
        ""
        if not excluded
        else " (excluded: " + "; ".join(f"{e['file']}: {e['reason']}" for e in excluded) + ")"
    )
    lone_sides: list[dict] = []
    report = {"rule": LONE_RULE if lone == "pool" else "refused", "lone": lone_sides}
    seen: set[int] = set()
    for i in range(len(files)):
        if int(counts[group[i]]) >= minimum or int(group[i]) in seen:
            continue
        seen.add(int(group[i]))
        members = [j for j in range(len(files)) if int(group[j]) == int(group[i])]
        names = ", ".join(files[j][0].name for j in members)
        side = "" if labels is None else f" passing {name(i)}"
        if lone == "pool" and int(lab[i]) in pooled_from:
            lone_sides.append(
                {
                    "files": [files[j][0].name for j in members],
                    "label": int(lab[i]),
                    "side": str(name(i)),
                }
            )
            continue
        if lone == "pool":
            raise ValueError(
                f"{files[i][1]}: this environment has {len(members)} demonstration(s){side} ("
                f"{names}) and no "
                f"environment has >= {minimum} demonstrations{side} to pool a weight variance from"
                f"{gone}: teach "
                f"more with python -m protorch.view --teach"
            )
        raise ValueError(
            f"{files[i][1]}: this environment has {len(members)} demonstration(s){side} ({names}); "
            "each needs "
            f">= {minimum} for a weight variance: teach more with python -m protorch.view --teach "
            "(it continues "
            f"the folder's last environment) or remove the pair{gone}"
        )
    return report


LONE_RULE = (
    "an environment's lone demonstration of a side takes the mean weight variance of the same "
    "side's "
    "environments with >= 2 demonstrations"
)


def accept_demo_folder(
    folder: DemoFolder, labels: Tensor | None, *, label_names: dict | None = None
) -> None:
    """The checks a folder passes before training (:func:`check_demo_groups` with lone sides
    pooled, the excluded recordings named in a refusal); the result goes into
    ``folder.report["sides"]`` and the report's summary lines (excluded recordings, findings)
    are printed, one ``[protorch] recordings:`` line each."""
    report = folder.report or {}
    sides = check_demo_groups(
        folder.envs,
        folder.files,
        labels,
        label_names=label_names,
        lone="pool",
        excluded=report.get("excluded"),
    )
    if folder.report:
        folder.report["sides"] = sides
        if sides["lone"]:
            folder.report["summary"].append(f"{len(sides['lone'])} lone side(s) ({sides['rule']})")
    for line in report.get("summary", []):
        print(f"[protorch] recordings: {line}", flush=True)


def read_marks(folder: str | Path) -> dict[int, list[str]]:
    """The quality marks the teach page recorded (``teach.json``): ``{K: [failed checks]}`` for
    the demonstrations kept although a check failed; ``{}`` without that file."""
    path = Path(folder) / MARKS_FILE
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
        return {
            int(k): list(v.get("flags", []))
            for k, v in data.get("demos", {}).items()
            if v.get("flags")
        }
    except (ValueError, AttributeError, TypeError) as exc:
        raise ValueError(f"{path}: not a teach-page record ({exc})") from None
