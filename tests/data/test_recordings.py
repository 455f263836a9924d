"""Timestamped recordings (protorch.data.recordings): reading by time, bad input, trimming,
alignment,
grouping, and the authors' folders read as before."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from protorch.data.demos import (
    PARTICLE_FORMAT,
    DemoFormat,
    load_human_demos,
    read_demo_folder,
    read_demos,
    write_demo,
)
from protorch.data.recordings import (
    Cleaning,
    align,
    clean,
    group_envs,
    read_recording,
    read_recordings,
    write_recording,
)

ROOT = Path(__file__).resolve().parents[2]
HUMAN = ROOT.parent / "shared" / "data" / "point_particle_human_demos"
FMT = DemoFormat(
    ("j1", "j2"),
    ("can_x", "can_y"),
    ((-2.0, 2.0),) * 2,
    ((-1.0, 1.0),) * 2,
    "the joint limits",
    "the table",
)


def path_at(phase: np.ndarray) -> np.ndarray:
    """A 2-joint motion over the phase [0, 1]: ``(n, 2)``."""
    return np.stack([np.sin(np.pi * phase) + phase, 0.5 * np.cos(2 * np.pi * phase) - phase], 1)


def minjerk(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0, 1)
    return u**3 * (10 - 15 * u + 6 * u**2)


def recording(
    t: np.ndarray,
    pre: float,
    motion: float,
    env=(0.1, 0.2),
    pause: tuple[float, float] | None = None,
):
    """Rows ``time, j1, j2, can_x, can_y`` of the motion at times ``t``: at rest ``pre`` s, then
    ``motion`` s of min-jerk progress (``pause = (progress, seconds)`` stops there), then at
    rest."""
    tm = t - pre
    if pause:
        stop = motion * _inverse_minjerk(pause[0])
        tm = np.where(tm > stop + pause[1], tm - pause[1], np.minimum(tm, stop))
    q = path_at(minjerk(tm / motion))
    env = np.broadcast_to(np.asarray(env, dtype=np.float64), (t.size, 2))
    return np.concatenate([t[:, None], q, env], 1)


def _inverse_minjerk(p: float) -> float:
    u = np.linspace(0, 1, 100001)
    return float(np.interp(p, minjerk(u), u))


def write(path: Path, table, header=("time", "j1", "j2", "can_x", "can_y")) -> Path:
    return write_recording(path, list(header), table)


def uneven_times(total: float, rate: float, rng) -> np.ndarray:
    dt = (1.0 / rate) * (1 + rng.uniform(-0.3, 0.3, int(total * rate * 1.5) + 10))
    t = np.concatenate([[0.0], np.cumsum(dt)])
    return t[t <= total]


def test_read_by_time_at_varying_rates(tmp_path):
    """The same motion recorded at 100 Hz and at an uneven ~1000 Hz, with different idle ends and
    the columns in another order, gives the same demonstration after trimming and resampling by
    time (within the interpolation error of 100 Hz sampling)."""
    rng = np.random.default_rng(0)
    a = recording(uneven_times(5.0, 100, rng), pre=0.5, motion=3.0)
    b = recording(uneven_times(6.0, 1000, rng), pre=1.4, motion=3.0)
    write(tmp_path / "a.csv", a)
    write(tmp_path / "b.csv", b[:, [0, 3, 2, 1, 4]], header=("time", "can_x", "j2", "j1", "can_y"))
    cl = Cleaning(align=False, samples=100)
    da, ra = clean(read_recording(tmp_path / "a.csv", FMT), cl)
    db, rb = clean(read_recording(tmp_path / "b.csv", FMT), cl)
    assert np.abs(da - db).max() < 0.01
    # the kept part: the motion, its onset and stop blurred by the 0.05 s smoothing window
    for r, pre in ((ra, 0.5), (rb, 1.4)):
        assert abs(r["trimmed_start_s"] - pre) <= 0.035 and abs(r["kept_s"] - 3.0) <= 0.07
    # with encoder noise (2e-4 rad at 1000 Hz) the onset is found within 0.1 s and the stop within
    # 0.3 s
    # (where less than 1 % of the path is left)
    noisy = b.copy()
    noisy[:, 1:3] += 2e-4 * rng.standard_normal((b.shape[0], 2))
    write(tmp_path / "n.csv", noisy)
    _, rn = clean(read_recording(tmp_path / "n.csv", FMT), cl)
    assert 0 <= rn["trimmed_start_s"] - 1.4 <= 0.1 and 0 <= 3.0 - rn["kept_s"] <= 0.4
    # without trimming the idle ends stay: the first 10 % of the 100 samples are still at rest
    off, r0 = clean(read_recording(tmp_path / "a.csv", FMT), cl.off())
    assert r0["trimmed_start_s"] == 0 and np.allclose(off[:8], off[0], atol=1e-9)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda t: t.__setitem__((5, 0), t[3, 0]), r"bad\.csv:7: time .* goes backwards from"),
        (lambda t: t.__setitem__((5, 0), t[4, 0]), r"bad\.csv:7: time .* repeats"),
        (lambda t: t.__setitem__((9, 2), np.nan), r"bad\.csv:11: j2 is nan \(NaN or infinite\)"),
        (
            lambda t: t.__setitem__((12, 1), 2.5),
            r"bad\.csv:14: j1 = 2\.5 lies outside the joint limits \[-2, 2\]",
        ),
    ],
)
def test_bad_rows_name_file_and_line(tmp_path, edit, message):
    table = recording(np.linspace(0, 2, 50), 0.2, 1.5)
    edit(table)
    write(tmp_path / "bad.csv", table)
    with pytest.raises(ValueError, match=message):
        read_recordings(tmp_path, FMT)


def test_bad_files(tmp_path):
    table = recording(np.linspace(0, 2, 50), 0.2, 1.5)
    write(tmp_path / "short.csv", table[:10])  # 0.37 s
    with pytest.raises(
        ValueError,
        match=r"short\.csv: the recording lasts 0\.367 s, shorter than the minimum 0\.5 s",
    ):
        read_recordings(tmp_path, FMT)
    (tmp_path / "short.csv").unlink()
    write(tmp_path / "nojoint.csv", table[:, [0, 1, 3, 4]], header=("time", "j1", "can_x", "can_y"))
    with pytest.raises(ValueError, match=r"nojoint\.csv:1: no column for joint 'j2'"):
        read_recordings(tmp_path, FMT)
    (tmp_path / "nojoint.csv").unlink()
    write(
        tmp_path / "still.csv", np.concatenate([table[:, :1], np.zeros((50, 2)), table[:, 3:]], 1)
    )
    with pytest.raises(
        ValueError,
        match=r"no recording remains to train on \(excluded: still\.csv: motionless: its "
        r"joints span at most 0 rad \(j1\), less than 0\.02 rad\)",
    ):
        read_recordings(tmp_path, FMT)
    (tmp_path / "still.csv").unlink()
    (tmp_path / "text.csv").write_text("time,j1,j2,can_x,can_y\n0,1,2,0,0\n0.1,x,2,0,0\n")
    with pytest.raises(ValueError, match=r"text\.csv:3: not a number"):
        read_recordings(tmp_path, FMT)
    (tmp_path / "text.csv").unlink()
    write(tmp_path / "a.csv", table)
    write_demo(tmp_path, 0, torch.zeros(3, 2), torch.zeros(2))
    with pytest.raises(ValueError, match=r"holds both \*\.csv recordings and trajK\.out"):
        read_demo_folder(tmp_path, FMT)


def test_env_from_sidecar(tmp_path):
    table = recording(np.linspace(0, 2, 50), 0.2, 1.5)
    write(tmp_path / "a.csv", table[:, :3], header=("time", "j1", "j2"))
    with pytest.raises(
        ValueError, match=r"a\.csv: no environment columns \['can_x', 'can_y'\] and no a\.json"
    ):
        read_recording(tmp_path / "a.csv", FMT)
    (tmp_path / "a.json").write_text('{"env": {"can_x": 0.3, "can_y": -0.25}}')
    assert read_recording(tmp_path / "a.csv", FMT).env.tolist() == [0.3, -0.25]


def test_alignment_half_speed_with_pause(tmp_path):
    """A recording replayed at half speed with a 1 s pause half way aligns to the original: after
    alignment both lie within 0.02 rad of each other at every sample and 0.01 RMS (before: > 0.3
    at worst; one of the 200 samples moves the motion by up to 0.04 rad), and the
    warp found moves the replay's phase by about the pause's share of it."""
    rng = np.random.default_rng(1)
    orig = recording(uneven_times(4.0, 500, rng), pre=0.5, motion=3.0)
    slow = recording(uneven_times(9.0, 200, rng), pre=0.8, motion=6.0, pause=(0.5, 1.0))
    write(tmp_path / "orig.csv", orig)
    write(tmp_path / "slow.csv", slow)
    folder, _ = read_recordings(tmp_path, FMT, Cleaning(align=False))
    before = np.abs(folder.demos[0].numpy() - folder.demos[1].numpy()).max()
    aligned, reports = align([d.numpy() for d in folder.demos])
    after = np.abs(aligned[0] - aligned[1]).max()
    rms = np.sqrt(((aligned[0] - aligned[1]) ** 2).sum(1).mean())
    assert before > 0.3 and after < 0.02 and rms < 0.01
    assert 0.03 < max(r["warp_max"] for r in reports) < 0.15  # the pause is 1 s of the ~6.6 s kept
    assert all(r["rms_to_medoid_after"] <= r["rms_to_medoid_before"] for r in reports)
    full, _ = read_recordings(tmp_path, FMT)  # the default cleaning aligns them the same way
    assert np.abs(full.demos[0].numpy() - full.demos[1].numpy()).max() < 0.02
    assert full.report["grouping"]["groups"] == 1 and full.report["warp_max"] > 0.03


def test_grouping_within_a_derived_tolerance():
    """Three environments 10+ cm apart, each measured three times with mm scatter: the derived
    tolerance lies between the scatter and the distances, and groups them; equal environments
    group exactly without a gap; a given tolerance is used as it is."""
    rng = np.random.default_rng(2)
    centres = np.array([[0.5, 0.1], [0.6, -0.1], [0.75, 0.05]])
    envs = np.repeat(centres, 3, 0) + 0.003 * rng.standard_normal((9, 2))
    group, tol, report = group_envs(envs, None)
    assert group.tolist() == [0, 0, 0, 1, 1, 1, 2, 2, 2]
    assert (
        report["derived"]
        and report["how"]["below"] < tol < report["how"]["above"]
        and 0.005 < tol < 0.1
    )
    assert group_envs(np.repeat(centres, 2, 0), None)[0].tolist() == [0, 0, 1, 1, 2, 2]
    assert group_envs(envs, 0.5)[0].tolist() == [0] * 9


def test_cleaning_settings():
    assert Cleaning.from_config({"trim": False, "align": False}) == Cleaning(trim=0.0, align=False)
    assert Cleaning.from_config({"group_tol": "auto"}).group_tol is None
    with pytest.raises(ValueError, match=r"task\.recordings: unknown setting\(s\) \['trimm'\]"):
        Cleaning.from_config({"trimm": 0.1})
    with pytest.raises(ValueError, match=r"task\.recordings\.trim must be a fraction"):
        Cleaning.from_config({"trim": 1.5})
    with pytest.raises(ValueError, match=r"task\.recordings\.group_tol must be auto or a distance"):
        Cleaning.from_config({"group_tol": -1})


def test_authors_folder_unchanged(tmp_path):
    """A trajK.out / envK.out folder reads exactly as read_demos reads it (no cleaning, no
    report, every row kept)."""
    write_demo(
        tmp_path,
        0,
        torch.tensor([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]),
        torch.tensor([1.0, 2, 5, 5, 8, 8]),
    )
    write_demo(
        tmp_path, 1, torch.tensor([[1.5, 2.0], [3.0, 4.5]]), torch.tensor([1.0, 2, 5, 5, 8, 8])
    )
    out, labels = read_demo_folder(tmp_path, PARTICLE_FORMAT, Cleaning())
    ref = read_demos(tmp_path, PARTICLE_FORMAT)
    assert labels is None and out.report == {} and out.indices == [0, 1]
    assert all(torch.equal(a, b) for a, b in zip(out.demos, ref.demos)) and torch.equal(
        out.envs, ref.envs
    )


@pytest.mark.skipif(
    not HUMAN.is_dir(), reason="the authors' human demonstrations are not on this machine"
)
def test_authors_human_demos_unchanged():
    demos, envs = load_human_demos(HUMAN)
    ref = read_demos(HUMAN, PARTICLE_FORMAT)
    assert len(demos) == len(ref.demos) > 0
    assert all(torch.equal(a, b) for a, b in zip(demos, ref.demos)) and torch.equal(envs, ref.envs)


def test_point_particle_recordings(tmp_path):
    """The point particle reads a recordings folder too (columns x, y and its 6 environment
    numbers): two recordings of one environment, at 60 and 240 Hz."""
    env = [1.0, 2.0, 5.0, 5.0, 8.0, 8.0]
    for name, rate in (("a", 60), ("b", 240)):
        t = np.arange(0, 3.0, 1 / rate)
        p = minjerk((t - 0.5) / 2.0)[:, None]
        xy = np.array([1.0, 2.0]) + p * np.array([7.0, 6.0])
        write_recording(
            tmp_path / f"{name}.csv",
            ["time", "x", "y", "start_x", "start_y", "wall_x", "hole_y", "goal_x", "goal_y"],
            np.concatenate([t[:, None], xy, np.tile(env, (t.size, 1))], 1),
        )
    demos, envs = load_human_demos(tmp_path)
    assert len(demos) == 2 and demos[0].shape == (200, 2) and torch.equal(envs[0], envs[1])
    assert torch.allclose(
        demos[0], demos[1], atol=0.05
    )  # 0.7 % of the motion: 60 Hz samples interpolated


def test_excluded_and_reported(tmp_path):
    """Two good recordings; one that lasts 0.37 s, one motionless, one whose motion is 0.3 s after
    trimming: the three are excluded (each listed with its reason) and the two cleaned as if
    alone. The findings of a good one: the can pushed 2 cm half way (its rows scattering 0.5 mm),
    an encoder wrap (2 pi) and 0.2 s without samples, each reported with its time."""
    rng = np.random.default_rng(3)
    t = np.linspace(0, 3, 301)
    good = recording(t, 0.5, 2.0)
    write(tmp_path / "a.csv", good)
    write(tmp_path / "b.csv", recording(t, 0.6, 1.8))
    alone, _ = read_recordings(tmp_path, FMT)
    write(tmp_path / "c_short.csv", good[:38])
    still = good.copy()
    still[:, 1:3] = good[0, 1:3] + 1e-4 * rng.standard_normal((301, 2))
    write(tmp_path / "d_still.csv", still)
    write(tmp_path / "e_quick.csv", recording(t, 1.0, 0.3))
    folder, _ = read_recordings(tmp_path, FMT)
    assert [e["file"] for e in folder.report["excluded"]] == [
        "c_short.csv",
        "d_still.csv",
        "e_quick.csv",
    ]
    reasons = [e["reason"] for e in folder.report["excluded"]]
    assert (
        reasons[0] == "the recording lasts 0.37 s, shorter than the minimum 0.5 s "
        "(task.recordings.min_duration)"
    )
    assert reasons[1].startswith("motionless: its joints span at most 0.000") and reasons[
        2
    ].startswith("it moves for 0.")
    assert (
        all(torch.equal(x, y) for x, y in zip(folder.demos, alone.demos)) and len(folder.demos) == 2
    )
    bad = good.copy()
    bad[150:, 3] += 0.02  # the can pushed 2 cm along x half way
    bad[:, 3:] += 5e-4 * rng.standard_normal((301, 2))
    write(tmp_path / "a.csv", bad)
    (tmp_path / "c_short.csv").unlink()
    r = read_recordings(tmp_path, FMT)[0].report["recordings"]
    assert r[0]["file"] == "a.csv" and r[0]["env_moved"]["drift"] == pytest.approx(0.02, abs=2e-3)
    assert 3e-4 < r[0]["env_moved"]["scatter"] < 1e-3 and "env_moved" not in r[1]
    bad[200:, 2] += 2 * np.pi  # an encoder wrap at 2 s
    bad = np.delete(bad, range(251, 270), axis=0)  # 0.2 s without samples at 2.5 s
    write(tmp_path / "a.csv", bad)
    with pytest.raises(
        ValueError, match=r"a\.csv:202: j2 = 5\.78462 lies outside the joint limits"
    ):
        read_recordings(tmp_path, FMT)  # the wrap leaves the limits here
    wide = DemoFormat(
        ("j1", "j2"),
        ("can_x", "can_y"),
        ((-9.0, 9.0),) * 2,
        ((-1.0, 1.0),) * 2,
        "the limits",
        "the table",
    )
    (r,) = [
        e for e in read_recordings(tmp_path, wide)[0].report["excluded"] if e["file"] == "a.csv"
    ]
    assert r["reason"].startswith(
        "it moves for 0.455 s only"
    )  # the jump is the peak speed the trimming measures against
    assert r["jumps"] == [
        {"time_s": 2.0, "joint": "j2", "step": pytest.approx(2 * np.pi, abs=0.01)}
    ]
    assert r["gaps"] == [{"time_s": 2.5, "seconds": pytest.approx(0.2)}]
    held = good.copy()
    held[:, 3:] += 5e-4 * rng.standard_normal((301, 2))
    held[100:, 3:] = held[99, 3:]  # the stream ends at 0.99 s of 3 s, held since
    write(tmp_path / "a.csv", held)
    r = read_recordings(tmp_path, FMT)[0].report
    assert (
        r["recordings"][0]["env_stream_ends_s"] == pytest.approx(0.99)
        and "env_moved" not in r["recordings"][0]
    )
    assert "a.csv: the environment stream ends at 0.99 s of 3.00 s (held since)" in r["summary"]
