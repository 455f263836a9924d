"""The loader of the authors' demonstration format, on the real human data (read in place from
../shared beside the repository, never copied) and on small hand-made folders."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from protorch.data.demos import (
    PARTICLE_FORMAT,
    DemoFormat,
    check_demo_groups,
    load_human_demos,
    read_demos,
    write_demo,
)
from protorch.tasks.point_particle import PointParticleTask

HUMAN = (
    Path(__file__).resolve().parents[2].parent / "shared" / "data" / "point_particle_human_demos"
)
needs_human = pytest.mark.skipif(
    not HUMAN.is_dir(),
    reason=f"human demonstrations not found at {HUMAN} (../shared beside the repo)",
)


@pytest.fixture(scope="module")
def human():
    return load_human_demos(HUMAN)


# ------------------------------------------------------------------ the real data
@needs_human
def test_human_data_shape_and_pairing(human):
    demos, envs = human
    assert len(demos) == 90 and envs.shape == (90, 6) and envs.dtype == torch.float64
    assert all(d.ndim == 2 and d.shape[1] == 2 and d.dtype == torch.float64 for d in demos)
    lengths = torch.tensor([len(d) for d in demos])
    assert 100 <= int(lengths.min()) and int(lengths.max()) <= 400
    # 30 environments, demonstrations 3i, 3i+1, 3i+2 share environment i
    torch.testing.assert_close(envs[0::3], envs[1::3], rtol=0, atol=0)
    torch.testing.assert_close(envs[0::3], envs[2::3], rtol=0, atol=0)
    assert torch.unique(envs, dim=0).shape[0] == 30
    # the first file, read independently
    first = [float(v) for v in (HUMAN / "env0.out").read_text().split()]
    torch.testing.assert_close(envs[0], torch.tensor(first, dtype=torch.float64))
    rows = (HUMAN / "traj0.out").read_text().strip().splitlines()
    assert len(demos[0]) == len(rows)
    assert demos[0][-1].tolist() == [float(v) for v in rows[-1].split(",")]


@needs_human
def test_human_envs_follow_the_sampler_constraints(human):
    _, envs = human
    sx, sy, wx, hy, gx, gy = envs.unbind(-1)
    assert bool(((wx >= 2) & (wx <= 8) & (hy >= 1) & (hy <= 9)).all())
    assert bool(((sx >= 0) & (sx <= wx - 1.5) & (gx >= wx + 1.5) & (gx <= 10)).all())
    assert bool(((sy >= 0) & (sy <= 10) & (gy >= 0) & (gy <= 10)).all())


@needs_human
def test_human_demos_against_the_task(human):
    """Measured: 89 of 90 succeed (98.9 %); none enters the wall (smallest clearance 0.49); the
    one failure ends 0.207 from its goal; starts are 0.02 to 0.15 off."""
    demos, envs = human
    task = PointParticleTask()
    ok = torch.stack([task.success(d, e) for d, e in zip(demos, envs)])
    collide = torch.stack([task.collides(d, e) for d, e in zip(demos, envs)])
    c = torch.stack([task.costs(d, e) for d, e in zip(demos, envs)])  # (90, 3)
    assert float(ok.double().mean()) >= 0.9
    assert int(collide.sum()) <= 3
    assert float((c[:, 0] <= 0.5).double().mean()) >= 0.95  # starts near the start
    assert float((c[:, 2] <= 0.5).double().mean()) >= 0.95  # ends near the goal
    assert float(c[:, 1].median()) < 0.5  # the hole is passed near its centre
    assert bool((c > 0).all())  # but nothing is exact: the data is imperfect


# ------------------------------------------------------------------ the format and its errors
def _write(folder: Path, k: int, traj: str | None, env: str | None) -> None:
    if traj is not None:
        (folder / f"traj{k}.out").write_text(traj)
    if env is not None:
        (folder / f"env{k}.out").write_text(env)


ENV_TEXT = "1\n5\n5\n5\n9\n5\n"


def test_small_folder_is_read_in_numeric_order(tmp_path):
    _write(tmp_path, 10, "3,3\n4,4\n", "2\n5\n5\n5\n9\n5\n")
    _write(tmp_path, 2, "1.0e+00,5.0e+00\n2,5\n\n", ENV_TEXT)  # a blank line is fine
    (tmp_path / "README.md").write_text("ignored")
    demos, envs = load_human_demos(tmp_path, dtype=torch.float32)
    assert [d.tolist() for d in demos] == [[[1, 5], [2, 5]], [[3, 3], [4, 4]]]
    assert envs.dtype == torch.float32 and envs[:, 0].tolist() == [1.0, 2.0]


def test_missing_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_human_demos(tmp_path / "nowhere")


def test_empty_folder(tmp_path):
    with pytest.raises(ValueError, match="no trajK.out"):
        load_human_demos(tmp_path)


@pytest.mark.parametrize(
    "which, message",
    [
        ("traj", r"traj files without env file for K = \[1\]"),
        ("env", r"env files without traj file for K = \[1\]"),
    ],
)
def test_unpaired_files(tmp_path, which, message):
    _write(tmp_path, 0, "1,5\n2,5\n", ENV_TEXT)
    _write(
        tmp_path, 1, "1,5\n2,5\n" if which == "traj" else None, ENV_TEXT if which == "env" else None
    )
    with pytest.raises(ValueError, match=message):
        load_human_demos(tmp_path)


@pytest.mark.parametrize(
    "traj, env, message",
    [
        ("1,5\n2,5,3\n", ENV_TEXT, r"traj0\.out:2: expected 2 value"),
        ("1,5\n2;5\n", ENV_TEXT, r"traj0\.out:2: expected 2 value"),
        ("1,5\nx,5\n", ENV_TEXT, r"traj0\.out:2: not a number"),
        ("1,5\nnan,5\n", ENV_TEXT, r"traj0\.out:2: NaN"),
        ("1,5\n2,inf\n", ENV_TEXT, r"traj0\.out:2: NaN or infinite"),
        ("1,5\n", ENV_TEXT, "at least 2 samples"),
        ("1,5\n2,5\n", "1\n5\n5\n5\n9\n", r"env0\.out: expected 6 numbers"),
        ("1,5\n2,5\n", "1\n5\nnan\n5\n9\n5\n", r"env0\.out:3: NaN"),
    ],
)
def test_bad_content(tmp_path, traj, env, message):
    _write(tmp_path, 0, traj, env)
    with pytest.raises(ValueError, match=message):
        load_human_demos(tmp_path)


# ------------------------------------------------------------------ the audit's bad files
def _write_pair(folder, k=0, traj="1,2\n3,4\n5,5\n", env="1\n2\n5\n5\n8\n8\n"):
    folder.mkdir(exist_ok=True)
    p = folder / f"traj{k}.out"
    p.write_bytes(traj) if isinstance(traj, bytes) else p.write_text(traj)
    (folder / f"env{k}.out").write_text(env)
    return folder


def test_a_binary_file_is_named(tmp_path):
    folder = _write_pair(tmp_path / "d", 3, traj=b"\x89PNG\r\n\x1a\n\xff\xfe\x00\x01")
    with pytest.raises(ValueError, match=r"traj3\.out.*not a text file"):
        load_human_demos(folder)


def test_a_row_outside_the_workspace_names_file_row_and_bound(tmp_path):
    folder = _write_pair(tmp_path / "d", traj="1,2\n1e308,1e308\n5,5\n")
    with pytest.raises(
        ValueError, match=r"traj0\.out:2: .*outside the workspace \[0(\.0)?, 10(\.0)?\]"
    ):
        load_human_demos(folder)


def test_an_environment_outside_the_workspace_is_refused(tmp_path):
    folder = _write_pair(tmp_path / "d", env="1\n2\n50\n5\n8\n8\n")  # wall_x = 50
    with pytest.raises(ValueError, match=r"env0\.out:3: wall_x = 50.*outside the workspace"):
        load_human_demos(folder)


def test_the_workspace_is_the_point_particle_tasks():
    from protorch.data.demos import WORKSPACE
    from protorch.tasks.point_particle import WORKSPACE as TASK_WORKSPACE

    assert tuple(WORKSPACE) == tuple(TASK_WORKSPACE)


# ------------------------------------------------------------------ writing, other formats, groups
def test_write_demo_round_trips_exactly_in_the_authors_layout(tmp_path):
    traj = torch.rand(7, 2, dtype=torch.float64) * 10
    env = torch.tensor([1 / 3, 2.0, 5.0, 5.5, 8.0, 8.0], dtype=torch.float64)
    write_demo(tmp_path, 4, traj, env)
    demos, envs = load_human_demos(tmp_path)
    assert torch.equal(demos[0], traj) and torch.equal(envs[0], env)  # %.18e is exact for float64
    rows = (tmp_path / "traj4.out").read_text().splitlines()
    assert len(rows) == 7 and rows[0] == ",".join(f"{v:.18e}" for v in traj[0].tolist())
    assert (tmp_path / "env4.out").read_text().splitlines()[0] == f"{1 / 3:.18e}"
    assert not list(tmp_path.glob(".*.tmp"))
    with pytest.raises(ValueError, match="finite"):
        write_demo(tmp_path, 5, torch.full((3, 2), float("nan")), env)
    assert not (tmp_path / "env5.out").exists()


def test_a_format_of_other_columns_names_them(tmp_path):
    fmt = DemoFormat(
        ("a", "b", "c"), ("p", "q"), ((0, 1),) * 3, ((0, 10), (0, 10)), "the box", "the room"
    )
    (tmp_path / "traj0.out").write_text("0,0,0\n0.5,2,0\n")
    (tmp_path / "env0.out").write_text("1\n2\n")
    with pytest.raises(ValueError, match=r"traj0\.out:2: b = 2 lies outside the box \[0, 1\]"):
        read_demos(tmp_path, fmt)
    (tmp_path / "traj0.out").write_text("0,0,0\n0.5,1,0\n")
    out = read_demos(tmp_path, fmt)
    assert (
        out.indices == [0]
        and out.envs.tolist() == [[1.0, 2.0]]
        and out.files[0][0].name == "traj0.out"
    )
    with pytest.raises(ValueError, match="one \\(lo, hi\\) per name"):
        DemoFormat(("a",), ("p",), ((0, 1), (0, 1)))


def test_an_environment_with_one_demonstration_is_named_by_its_files(tmp_path):
    env = torch.tensor([1.0, 2.0, 5.0, 5.0, 8.0, 8.0], dtype=torch.float64)
    for k in range(3):
        write_demo(tmp_path, k, torch.rand(3, 2, dtype=torch.float64), env + (k == 2))
    out = read_demos(tmp_path, PARTICLE_FORMAT)
    with pytest.raises(
        ValueError, match=r"env2\.out: this environment has 1 demonstration\(s\) \(traj2\.out\)"
    ):
        check_demo_groups(out.envs, out.files)
    check_demo_groups(out.envs[:2], out.files[:2])  # two of one environment are enough


def test_lone_sides_take_their_sides_pooled_variance(tmp_path):
    """Three environments: A two left + one right, B two right, C one left + two right. The lone
    entries (A right, C left) are kept, their weight variance the mean of their side's measured
    ones (A right: B right's and C right's; C left: A left's); the others as measured. Refused
    only where a side has no environment with 2 demonstrations."""
    from protorch import ProMP
    from protorch.loop.initial import demonstration_dataset

    gen = torch.Generator().manual_seed(0)
    envs = torch.tensor([[0.0, 0.0]] * 3 + [[1.0, 0.0]] * 2 + [[2.0, 0.0]] * 3, dtype=torch.float64)
    labels = torch.tensor([0, 0, 1, 1, 1, 0, 1, 1])
    demos = [torch.randn(30, 2, generator=gen, dtype=torch.float64).cumsum(0) for _ in range(8)]
    files = [(Path(f"t{i}"), Path(f"e{i}")) for i in range(8)]
    with pytest.raises(
        ValueError, match=r"e2: this environment has 1 demonstration\(s\) passing right \(t2\)"
    ):
        check_demo_groups(envs, files, labels, label_names={0: "left", 1: "right"})
    rep = check_demo_groups(envs, files, labels, label_names={0: "left", 1: "right"}, lone="pool")
    assert rep["lone"] == [
        {"files": ["t2"], "label": 1, "side": "right"},
        {"files": ["t5"], "label": 0, "side": "left"},
    ]
    promp = ProMP(2, num_basis=5, num_steps=30)
    ds = demonstration_dataset(promp, demos, envs, labels=labels, lone="pool")
    w = promp.weights(demos).to(torch.float64)
    var = lambda idx: (w[idx] - w[idx].mean(0)).pow(2).mean(0)
    assert ds.env.shape[0] == 5 and ds.label.tolist() == [
        0,
        1,
        1,
        0,
        1,
    ]  # A left, A right, B, C left, C right
    for k, want in enumerate(
        [var([0, 1]), (var([3, 4]) + var([6, 7])) / 2, var([3, 4]), var([0, 1]), var([6, 7])]
    ):
        assert torch.allclose(ds.var[k], want, rtol=1e-9, atol=0)
    assert torch.allclose(ds.mean[1], w[2]) and torch.allclose(ds.mean[3], w[5])
    with pytest.raises(ValueError, match=r"has 1 demonstration; a weight variance needs >= 2"):
        demonstration_dataset(promp, demos, envs, labels=labels)
    keep = [0, 1, 2, 3, 4]  # A (2 left, 1 right), B (2 right): right pools from B
    ds = demonstration_dataset(
        promp, [demos[i] for i in keep], envs[keep], labels=labels[keep], lone="pool"
    )
    assert torch.allclose(ds.var[1], var([3, 4]), rtol=1e-9, atol=0)
    only = [2, 3, 4, 5]  # no environment with 2 left demonstrations: C's lone left cannot be pooled
    with pytest.raises(
        ValueError,
        match=r"e5: this environment has 1 demonstration\(s\) passing left \(t5\) and no "
        r"environment has >= 2 demonstrations passing left to pool",
    ):
        check_demo_groups(
            envs[only],
            [files[i] for i in only],
            labels[only],
            label_names={0: "left", 1: "right"},
            lone="pool",
        )
