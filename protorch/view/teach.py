"""A teaching session, as plain functions of recorded samples (no browser, no viser).

:class:`TeachSession` holds the folder being written, the environment being taught, the
demonstration on show and the progress. :meth:`~TeachSession.record` resamples recorded samples
(mouse positions, or joint angles) linearly to the task's ``num_steps`` time steps over a common
phase (:func:`protorch.primitives.promp.resample`, what the ProMP fit does with any
demonstration) and runs the quality checks (:mod:`protorch.view.teach_tasks`);
:meth:`~TeachSession.keep` writes the resampled demonstration at once as ``trajK.out`` /
``envK.out`` (:func:`protorch.data.demos.write_demo`, atomic; with ``fmt="csv"`` the raw samples
at their times as a timestamped recording ``demoK.csv``, :mod:`protorch.data.recordings`) and then
the quality record
``teach.json``; a flagged demonstration is kept only with ``insist=True`` and stays marked there.
After ``per_env`` kept demonstrations the next proposed environment comes.

A session opened on a folder that already holds demonstrations continues it: the files are read
and checked (a malformed file is refused, naming file and line), an environment left with fewer
than ``per_env`` demonstrations is taught on, and new files take the next free ``K``. With a
trained run, :func:`failing_envs` proposes the environments where the run's map fails first.
"""

from __future__ import annotations

import json
import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..data.demos import MARKS_FILE, demo_files, read_demos, write_demo
from ..data.files import atomic_write_bytes, remove_stale_tmp
from ..data.recordings import TIME, read_recording, recording_files, write_recording
from ..gp.model import label_aware_mean
from ..primitives.promp import resample
from ..tasks.arm.reach import ArmReachTask
from .teach_tasks import Quality

__all__ = ["Pending", "TeachSession", "failing_envs"]

_CSV_NAME = re.compile(r"^demo(\d+)\.csv$")


@dataclass
class Pending:
    """The demonstration on show: ``raw (n, D)`` as recorded, ``traj (T, D)`` resampled (what
    is written), its :class:`~protorch.view.teach_tasks.Quality` and the path drawn ``(T, 3)``."""

    raw: Tensor
    traj: Tensor
    quality: Quality
    path: np.ndarray
    times: Tensor | None = (
        None  # (n,) seconds of the raw samples (the recordings format writes them)
    )


def failing_envs(run, envs: Tensor) -> Tensor:
    """The environments ``envs (n, E)`` reordered: those where the run's map fails first (its
    mean trajectory, the arm's label-aware one, does not succeed), each group in its order."""
    model, ref = run.model, run.model.promp.basis
    q = torch.as_tensor(envs).to(ref)
    with torch.no_grad():
        if model.task_name == ArmReachTask.name:
            mean = label_aware_mean(model.env_map, model.promp, run.task, q, dtype=ref.dtype).mean
            ok = run.task.success(model.promp.trajectory(mean), q)  # (n,)
        else:
            ok = run.task.success(model.mean_trajectory(q), q)  # (n,)
    order = torch.cat([torch.nonzero(~ok.cpu()).flatten(), torch.nonzero(ok.cpu()).flatten()])
    return torch.as_tensor(envs)[order]


def _recover(folder: Path, known: set) -> list[str]:
    """Remove what an interrupted keep can leave: temporary files, and an ``envK.out`` without
    its trajectory at the highest ``K`` that the record does not know. Returns notes."""
    notes = [f"removed {p.name} (an interrupted write)" for p in remove_stale_tmp(folder)]
    trajs, envs = demo_files(folder)
    orphans = sorted(envs.keys() - trajs.keys())
    if orphans and orphans[-1] == max(envs) and orphans[-1] not in known:
        envs[orphans[-1]].unlink()
        notes.append(
            f"removed env{orphans[-1]}.out: its keep was interrupted before the trajectory was "
            "written"
        )
    return notes


class TeachSession:
    """Teach ``teach`` (:class:`~protorch.view.teach_tasks.ParticleTeach` or
    :class:`~protorch.view.teach_tasks.ArmTeach`) into ``folder``.

    Args:
        per_env: demonstrations per environment (>= 2: a weight variance needs 2).
        num_envs: environments to teach (the panel counts towards it; more may be taught).
        num_steps: ``T``, the time grid the demonstrations are resampled to (the ProMP's steps).
        proposals: ``(P, E)`` environments offered in order (default: random, ``seed``).
        fmt: ``"out"``: ``trajK.out`` / ``envK.out`` (resampled to ``num_steps``); ``"csv"``:
        timestamped
            recordings ``demoK.csv`` (:mod:`protorch.data.recordings`: the raw samples at their
            times, the
            environment in every row; cleaned when read for training).
    """

    def __init__(
        self,
        teach,
        folder: str | Path,
        *,
        per_env: int = 3,
        num_envs: int = 30,
        num_steps: int = 100,
        proposals: Tensor | None = None,
        seed: int = 0,
        fmt: str = "out",
    ) -> None:
        if fmt not in ("out", "csv"):
            raise ValueError(f"fmt must be out or csv, got {fmt!r}")
        self.fmt = fmt
        if int(per_env) < 2 or int(num_envs) < 1 or int(num_steps) < 2:
            raise ValueError(
                f"need per_env >= 2, num_envs >= 1, num_steps >= 2; "
                f"got {per_env}, {num_envs}, {num_steps}"
            )
        self.teach, self.folder = teach, Path(folder)
        self.per_env, self.num_envs, self.num_steps = int(per_env), int(num_envs), int(num_steps)
        self.lock = threading.RLock()
        self.folder.mkdir(parents=True, exist_ok=True)
        self.record_data = self._read_record()
        self.notes = _recover(self.folder, {int(k) for k in self.record_data["demos"]})
        self.envs: list[Tensor] = []  # the folder's environments, in order of first appearance
        self.counts: list[int] = []  # demonstrations of each
        self.sides: list[list[int]] = []  # the arm: the side of each (to flag a lone side)
        self.paths: list[list[np.ndarray]] = []  # the drawn path (T, 3) of each
        self.next_k = 0
        self._read_folder()
        if proposals is None:
            proposals = teach.sample_envs(
                4 * self.num_envs + 16, torch.Generator().manual_seed(int(seed))
            )
        self.proposals = torch.as_tensor(proposals, dtype=torch.float64)  # (P, E)
        self.offered = 0  # proposals used; those already in the folder are passed over
        self.pending: Pending | None = None
        if self.envs and self.counts[-1] < self.per_env:
            self.env = self.envs[-1].clone()  # continue the last environment
        else:
            self.env = self._proposal()

    # ------------------------------------------------------------------ the folder
    def _read_record(self) -> dict:
        path = self.folder / MARKS_FILE
        if not path.is_file():
            return {
                "task": self.teach.name,
                "columns": list(self.teach.fmt.columns),
                "env_names": list(self.teach.fmt.env_names),
                "demos": {},
            }
        try:
            data = json.loads(path.read_text())
            task = data["task"]
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{path}: not a teach-page record ({exc})") from None
        if task != self.teach.name:
            raise ValueError(
                f"{self.folder} holds {task} demonstrations ({path}); teach {self.teach.name} "
                "elsewhere"
            )
        return data

    def _read_folder(self) -> None:
        trajs, envs = demo_files(self.folder)
        csvs = recording_files(self.folder)
        if (trajs or envs) and (csvs or self.fmt == "csv") or (csvs and self.fmt == "out"):
            raise ValueError(
                f"{self.folder} holds {'*.csv recordings' if csvs else 'trajK.out files'}: teach "
                "the "
                f"{'csv' if csvs else 'out'} format there (--format), or another folder"
            )
        if csvs:
            found = [
                (int(m.group(1)), read_recording(p, self.teach.fmt))
                for p in csvs
                if (m := _CSV_NAME.match(p.name))
            ]  # refuses a malformed file, naming file and line
            indices = [k for k, _ in found]
            demos = [torch.as_tensor(r.values) for _, r in found]
            envs_t = [torch.as_tensor(r.env) for _, r in found]
        elif trajs or envs:
            out = read_demos(
                self.folder, self.teach.fmt
            )  # refuses a malformed file, naming file and line
            indices, demos, envs_t = out.indices, out.demos, list(out.envs)
        else:
            return
        if not indices:
            return
        for k, d, e in zip(indices, demos, envs_t):
            i = next((j for j, f in enumerate(self.envs) if torch.equal(f, e)), None)
            i = self._add_env(e) if i is None else i
            self.counts[i] += 1
            traj = resample(d, self.num_steps)  # (T, D)
            self.paths[i].append(self.teach.path(traj))
            if self.teach.kind == "arm":
                traj = traj.to(self.teach.task.kinematics.lower)
                self.sides[i].append(int(self.teach.task.side(traj, e.to(traj))))
        self.next_k = max(indices) + 1

    def _add_env(self, env: Tensor) -> int:
        self.envs.append(env.clone())
        self.counts.append(0)
        self.sides.append([])
        self.paths.append([])
        return len(self.envs) - 1

    def _write_record(self) -> None:
        text = json.dumps(self.record_data, indent=1, sort_keys=True, allow_nan=False)
        atomic_write_bytes(self.folder / MARKS_FILE, text.encode())

    # ------------------------------------------------------------------ environments
    def _proposal(self) -> Tensor:
        """The next proposed environment the folder does not hold yet."""
        while True:
            while self.offered >= self.proposals.shape[0]:  # more than proposed: draw on
                more = self.teach.sample_envs(
                    self.proposals.shape[0], torch.Generator().manual_seed(self.offered)
                )
                self.proposals = torch.cat([self.proposals, more.to(self.proposals)])
            env = self.proposals[self.offered].clone()
            self.offered += 1
            if not any(torch.equal(env, e) for e in self.envs):
                return env

    def _index(self) -> int | None:
        return next((j for j, f in enumerate(self.envs) if torch.equal(f, self.env)), None)

    @property
    def kept_here(self) -> int:
        """Demonstrations kept for the current environment."""
        i = self._index()
        return 0 if i is None else self.counts[i]

    @property
    def locked(self) -> bool:
        """The environment cannot change: some but not ``per_env`` demonstrations are
        kept for it."""
        return 0 < self.kept_here < self.per_env

    def kept_paths(self) -> list[np.ndarray]:
        """The drawn paths ``[(T, 3)]`` of the current environment's kept demonstrations."""
        i = self._index()
        return [] if i is None else list(self.paths[i])

    @property
    def envs_done(self) -> int:
        """Environments with at least ``per_env`` demonstrations."""
        return sum(c >= self.per_env for c in self.counts)

    @property
    def kept(self) -> int:
        return sum(self.counts)

    @property
    def marked(self) -> int:
        """Kept demonstrations whose checks failed (kept because the user insisted)."""
        return sum(bool(v.get("flags")) for v in self.record_data["demos"].values())

    def set_env(self, env) -> None:
        """Teach ``env (E,)`` next (refused while :attr:`locked`); a new environment drops the
        demonstration on show."""
        env = torch.as_tensor(env, dtype=torch.float64).reshape(-1)
        with self.lock:
            if env.shape == self.env.shape and torch.equal(env, self.env):
                return  # unchanged: the demonstration on show stays
            if self.locked:
                raise ValueError(
                    f"{self.kept_here} of {self.per_env} demonstrations are kept for this "
                    "environment: "
                    "finish it first"
                )
            if env.shape != self.env.shape:
                raise ValueError(f"env must have {self.env.numel()} values, got {env.numel()}")
            self.env, self.pending = env.clone(), None

    def next_env(self) -> Tensor:
        """Move to the next proposed environment (refused while :attr:`locked`)."""
        with self.lock:
            if self.locked:
                raise ValueError(
                    f"{self.kept_here} of {self.per_env} demonstrations are kept for this "
                    "environment: "
                    "finish it first"
                )
            self.env, self.pending = self._proposal(), None
            return self.env

    # ------------------------------------------------------------------ demonstrations
    def record(self, raw, times=None, **extra) -> Pending:
        """The demonstration ``raw (n, D)`` (n >= 1 recorded samples, taken at ``times (n,)`` s;
        default: 60 per second) resampled to ``num_steps``, checked and put on show (replacing the
        one shown). ``extra`` goes to the checks (the arm: ``ik_error``)."""
        raw = torch.as_tensor(raw, dtype=torch.float64).reshape(
            -1, len(self.teach.fmt.columns)
        )  # (n, D)
        times = (
            torch.arange(raw.shape[0], dtype=torch.float64) / 60
            if times is None
            else torch.as_tensor(times, dtype=torch.float64).reshape(-1)
        )  # (n,)
        if times.shape[0] != raw.shape[0]:
            raise ValueError(
                f"times must have one entry per sample ({raw.shape[0]}), got {times.shape[0]}"
            )
        if raw.shape[0] < 1 or not bool(torch.isfinite(raw).all()):
            raise ValueError(
                f"a demonstration needs >= 1 finite sample, got shape {tuple(raw.shape)}"
            )
        with self.lock:
            src = raw if raw.shape[0] >= 2 else raw.expand(2, -1)  # one sample: a point held still
            traj = resample(src, self.num_steps)  # (T, D)
            i = self._index()
            sides = tuple(self.sides[i]) if i is not None and self.teach.kind == "arm" else ()
            quality = self.teach.quality(raw, traj, self.env, sides=sides, **extra)
            self.pending = Pending(raw, traj, quality, self.teach.path(traj), times)
            return self.pending

    def discard(self) -> None:
        """Drop the demonstration on show."""
        with self.lock:
            self.pending = None

    def keep(self, *, insist: bool = False) -> int:
        """Write the demonstration on show as ``trajK.out`` / ``envK.out`` and record its checks;
        return ``K``. A flagged one needs ``insist=True`` (it is then marked in ``teach.json``).
        With ``per_env`` kept for this environment the next one is proposed."""
        with self.lock:
            p = self.pending
            if p is None:
                raise ValueError("no demonstration to keep: draw one first")
            if not p.quality.ok and not insist:
                raise ValueError(
                    "this demonstration failed its checks ("
                    + "; ".join(p.quality.messages)
                    + "): keep it anyway, or discard it"
                )
            k = self.next_k
            if self.fmt == "csv":
                self._write_recording(k, p)
            else:
                write_demo(self.folder, k, p.traj, self.env)
            self.next_k += 1
            i = self._index()
            i = self._add_env(self.env) if i is None else i
            self.counts[i] += 1
            self.paths[i].append(p.path)
            if "label" in p.quality.values:
                self.sides[i].append(int(p.quality.values["label"]))
            self.record_data["demos"][str(k)] = {
                "env": i,
                "samples": int(p.raw.shape[0]),
                "num_steps": self.num_steps,
                "flags": list(p.quality.flags),
                "messages": p.quality.messages,
                "insisted": bool(insist and not p.quality.ok),
                "values": p.quality.values,
                "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            }
            self._write_record()
            self.pending = None
            if self.counts[i] >= self.per_env:
                self.env = self._proposal()
            return k

    def _write_recording(self, k: int, p: Pending) -> None:
        """``demoK.csv``: the raw samples at their times from 0 (samples whose time does not
        increase dropped; one sample held for a second), the environment in every row."""
        keep = torch.cat(
            [torch.ones(1, dtype=torch.bool), p.times[1:] > torch.cummax(p.times, 0).values[:-1]]
        )
        t, raw = p.times[keep] - p.times[0], p.raw[keep]  # (n,), (n, D)
        if t.shape[0] < 2:
            t, raw = torch.tensor([0.0, 1.0], dtype=torch.float64), raw[:1].expand(2, -1)
        env = self.env.to(torch.float64).expand(t.shape[0], -1)  # (n, E)
        fmt = self.teach.fmt
        write_recording(
            self.folder / f"demo{k}.csv",
            [TIME, *fmt.columns, *fmt.env_names],
            torch.cat([t[:, None], raw, env], 1).numpy(),
        )

    # ------------------------------------------------------------------ progress
    def progress(self) -> dict:
        """Environments done (of ``num_envs``), kept here (of ``per_env``), kept and
        marked in all."""
        with self.lock:
            return {
                "envs_done": self.envs_done,
                "num_envs": self.num_envs,
                "kept_here": self.kept_here,
                "per_env": self.per_env,
                "kept": self.kept,
                "marked": self.marked,
                "finished": self.envs_done >= self.num_envs,
            }
