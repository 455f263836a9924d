"""The C++ loop of examples/cpp (libtorch alone, no Python in its process) drives the two
AOTInductor programs of ``policy.export(folder, aoti=True)``: the tracker every 1 ms tick, the
planner every few ticks, each one's state passed in and out; its references equal the threaded
Python policy's given the same inputs (the same plans made at the same ticks)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest
import torch

from examples.cpp.raw import read_outputs, write_inputs
from tests.control.test_policy import toy_policy
from tests.policy.test_export_programs import python_loop
from tests.policy.test_two_rate import walk

F64 = torch.float64
ROOT = Path(__file__).resolve().parents[2]
TORCH_CMAKE = Path(torch.utils.cmake_prefix_path) / "Torch" / "TorchConfig.cmake"


def missing_tools() -> str:
    """Why the example cannot be built here ('' where it can)."""
    if shutil.which("c++") is None and shutil.which("g++") is None:
        return "no C++ compiler on this machine"
    if shutil.which("cmake") is None:
        return "no cmake on this machine"
    if not TORCH_CMAKE.exists():
        return f"this torch has no cmake files ({TORCH_CMAKE} missing)"
    return ""


def build_example(build: Path) -> Path:
    """examples/cpp configured and built in ``build``: the binary's path."""
    cmake = ["cmake", "-S", str(ROOT / "examples" / "cpp"), "-B", str(build)]
    cmake += ["-DCMAKE_BUILD_TYPE=Release", f"-DCMAKE_PREFIX_PATH={torch.utils.cmake_prefix_path}"]
    for cmd in (cmake, ["cmake", "--build", str(build), "-j", "2"]):
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return build / "exported_loop"


@pytest.mark.slow
@pytest.mark.skipif(bool(missing_tools()), reason=missing_tools() or "-")
def test_the_cpp_loop_on_the_aoti_programs_equals_the_threaded_policy(tmp_path):
    """The toy map (two classes, a switch on the way, environment jumps every 97 ticks), a plan
    every 5 ticks, the class decided every 20 ms, the first tick at the measured joints: q, qd,
    qdd to 1e-9, the same label and plan time at every one of the 400 ticks; a folder whose
    planner is not compiled and a short input file are one clear error each."""
    binary = build_example(tmp_path / "build")
    pol = toy_policy(nearest_k=8, planner="thread", plan_period=1e6)
    folder = pol.export(tmp_path / "programs", aoti=True)
    envs, q0 = walk(400), torch.tensor([0.1, -0.2], dtype=F64)  # (400, 2), (2,)
    qd0 = torch.zeros_like(q0)
    write_inputs(tmp_path / "in", envs, q0, qd0)
    proc = subprocess.run(
        [str(binary), str(folder), str(tmp_path / "in"), "--out", str(tmp_path / "out")]
        + ["--plan-every", "5"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.startswith("400 ticks, a plan every 5: tracker wall median")
    got = read_outputs(tmp_path / "out", 2)
    want = python_loop(pol, envs, q0, qd0, 5)
    for k in ("q", "qd", "qdd"):
        assert got[k].shape == (400, 2)
        torch.testing.assert_close(got[k], torch.stack(want[k]), rtol=0, atol=1e-9)
    assert got["label"].tolist() == want["label"]
    assert set(want["label"]) == {0, 1}  # a switch on the way
    assert got["plan_t"].tolist() == want["plan_t"]
    assert got["tracker_s"].shape == (400,) and bool((got["tracker_s"] > 0).all())
    assert got["planner_s"].shape == (80,)  # a plan every 5 ticks
    pol.close()

    meta = json.loads((folder / "programs.json").read_text())
    (folder / "programs.json").write_text(
        json.dumps({**meta, "aoti": {**meta["aoti"], "planner": False}}, indent=1)
    )
    proc = subprocess.run(
        [str(binary), str(folder), str(tmp_path / "in")], capture_output=True, text=True
    )
    assert proc.returncode == 1
    assert "planner.pt2 of" in proc.stderr and "not an AOTInductor package" in proc.stderr
    (folder / "programs.json").write_text(json.dumps(meta, indent=1))
    (tmp_path / "in" / "q0.f64").write_bytes(b"\0" * 8)  # one joint of two
    proc = subprocess.run(
        [str(binary), str(folder), str(tmp_path / "in")], capture_output=True, text=True
    )
    assert (
        proc.returncode == 1 and "q0.f64: 8 bytes, not a whole number of rows of 2" in proc.stderr
    )
