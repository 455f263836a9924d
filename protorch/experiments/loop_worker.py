"""A loop baseline in a child process, so that it runs beside the method's loop on a second core.

An experiment's loop baselines (the point particle's RWR loop, the arm's loop without labels) do
not depend on the method's loop: :class:`LoopWorker` starts a Python process running
:func:`main` with the experiment's class, its constructor's keyword
arguments (JSON: numbers, strings, lists, dicts, dtypes, devices) and the baseline's name on
stdin. The child rebuilds the experiment (its demonstrations and test environments are
seeded, so they are the same), runs that loop with one torch thread into
``<run_dir>/baselines/<name>`` and exits; the parent then resumes the finished loop from its
checkpoint (no step is left, so it only reads it back) and evaluates the map as it would have.
Every number is the one the same loop gives in the parent at one thread.

The child writes only the loop's checkpoint and metrics, atomically, like the parent's loop, so
a killed run leaves no half-written file and resumes (the child resumes its loop too). It exits
when its parent does (Linux: ``PR_SET_PDEATHSIG``; elsewhere at the next loop step), and the
parent stops it when the run fails.
"""

from __future__ import annotations

import ctypes
import importlib
import json
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import torch

from ..threads import torch_threads

__all__ = ["LoopWorker", "encode_settings", "decode_settings", "main"]


def encode_settings(x):
    """Constructor keyword arguments as JSON (tuples become lists); ``TypeError`` for anything
    else than numbers, strings, ``None``, lists, tuples, dicts with string keys, dtypes, devices."""
    if isinstance(x, torch.dtype):
        return {"__dtype__": str(x).removeprefix("torch.")}
    if isinstance(x, torch.device):
        return {"__device__": str(x)}
    if isinstance(x, dict):
        if not all(isinstance(k, str) for k in x):
            raise TypeError("a worker process takes dicts with string keys only")
        return {k: encode_settings(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [encode_settings(v) for v in x]
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    raise TypeError(f"a worker process cannot be given a {type(x).__name__}")


def decode_settings(x):
    """The inverse of :func:`encode_settings` (lists stay lists)."""
    if isinstance(x, dict):
        if set(x) == {"__dtype__"}:
            return getattr(torch, x["__dtype__"])
        if set(x) == {"__device__"}:
            return torch.device(x["__device__"])
        return {k: decode_settings(v) for k, v in x.items()}
    if isinstance(x, list):
        return [decode_settings(v) for v in x]
    return x


class LoopWorker:
    """A child process (:func:`main`) running the loop baseline ``variant`` of
    ``experiment`` (built from ``settings``, its constructor's keyword arguments) into ``run_dir``.
    :meth:`wait` returns once it finished (``RuntimeError`` with its last error lines if it
    failed); :meth:`stop` ends it."""

    def __init__(
        self, experiment, settings: dict, variant: str, run_dir: Path, resume: bool
    ) -> None:
        cls = type(experiment)
        spec = {
            "class": f"{cls.__module__}:{cls.__qualname__}",
            "settings": encode_settings(settings),
            "variant": variant,
            "run_dir": str(run_dir),
            "resume": bool(resume),
            "parent": os.getpid(),
        }
        self.variant = variant
        self.log = tempfile.TemporaryFile(
            mode="w+b"
        )  # its stderr: warnings are passed on, errors reported
        env = {
            **os.environ,
            "OMP_NUM_THREADS": "1",
            "PYTHONPATH": os.pathsep.join(
                [
                    str(Path(__file__).resolve().parents[2]),
                    *filter(None, [os.environ.get("PYTHONPATH")]),
                ]
            ),
        }
        code = "from protorch.experiments.loop_worker import main; main()"
        self.proc = subprocess.Popen(
            [sys.executable, "-c", code],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self.log,
            env=env,
        )
        self.proc.stdin.write(json.dumps(spec).encode())
        self.proc.stdin.close()

    def wait(self) -> dict:
        """Wait for the child; returns what it reports (``resumed_from``: the step its loop
        continued after, ``None`` for a fresh loop)."""
        out = self.proc.stdout.read()
        rc = self.proc.wait()
        self.log.seek(0)
        err = self.log.read().decode(errors="replace")
        self.log.close()
        if rc != 0:
            tail = "\n".join(err.strip().splitlines()[-15:])
            raise RuntimeError(
                f"the {self.variant} loop's worker process failed (exit code {rc}):\n{tail}"
            )
        if err.strip():
            sys.stderr.write(err)
        return json.loads(out.decode().strip().splitlines()[-1])

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if not self.log.closed:
            self.log.close()


def _exit_with(parent: int) -> None:
    """End this process when ``parent`` ends (Linux asks the kernel; the loop also checks)."""
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:
        sys.exit("the parent process is gone")


def main() -> None:
    """The child: the spec on stdin (see :class:`LoopWorker`)."""
    spec = json.loads(sys.stdin.read())
    parent = int(spec["parent"])
    _exit_with(parent)
    module, _, name = spec["class"].partition(":")
    cls = getattr(importlib.import_module(module), name)

    def parent_alive(row) -> None:
        if os.getppid() != parent:
            sys.exit("the parent process is gone")

    with torch_threads(1):
        exp = cls(**decode_settings(spec["settings"])).build()
        res = exp.run_loop(
            spec["variant"],
            run_dir=Path(spec["run_dir"]),
            resume=spec["resume"],
            progress=False,
            on_step=parent_alive,
        )
    print(json.dumps({"resumed_from": res.resumed_from}), flush=True)
