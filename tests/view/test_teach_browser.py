"""The teach page in a real browser: headless Chromium draws demonstrations with the mouse
through the page (playwright's ``mouse.down`` / ``move`` / ``up``: viser's scene-node drag events
for the particle, its transform-control drag for the arm's hand), clicks Keep / Keep anyway, the
page is closed mid-stroke and reopened, and the files written are checked and trained from.

Each pointer waypoint is waited for on the server before the next move (viser sends at most one
drag update per 50 ms, the latest position), so the recorded stroke passes through every
waypoint; the checks' ``min_samples`` is lowered because a waypoint stroke has fewer samples than
a person's (about 20 a second). Skipped without Chromium or playwright (conftest ``browser``).
"""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from protorch.data.demos import PARTICLE_FORMAT, read_demos, read_marks
from protorch.experiments import arm_reach, point_particle
from protorch.tasks.arm.demos import arm_demo_format
from protorch.view.draw import screen_points
from protorch.view.teach import TeachSession
from protorch.view.teach_server import Teacher
from protorch.view.teach_tasks import ArmTeach, ParticleTeach

ENV_A = [1.0, 2.0, 5.0, 6.5, 9.0, 3.0]  # wall x in [4, 6], hole y in (5.5, 7.5)
ENV_B = [0.5, 8.0, 4.0, 3.0, 8.5, 7.0]  # wall x in [3, 5], hole y in (2, 4)
HOLE_A = [(1.0, 2.0), (2.5, 4.5), (3.6, 6.4), (5.0, 6.5), (6.4, 6.4), (7.8, 4.6), (9.0, 3.0)]
WALL_A = [(1.0, 2.0), (3.0, 2.5), (5.0, 2.5), (7.0, 2.8), (9.0, 3.0)]
HOLE_B = [(0.5, 8.0), (1.6, 5.5), (2.6, 3.2), (4.0, 3.0), (5.4, 3.2), (7.2, 5.5), (8.5, 7.0)]
HOLE_B2 = [(0.55, 7.95), (1.4, 5.2), (2.5, 2.9), (4.0, 2.7), (5.5, 2.9), (7.0, 5.0), (8.45, 7.0)]
ENV_C = [1.0, 5.0, 6.0, 5.0, 9.5, 5.0]  # the next one, where the page is closed mid-stroke


def wait_until(cond, what: str, timeout: float = 120.0) -> None:
    """Poll ``cond`` (software WebGL on a busy machine can take tens of seconds per first frame)."""
    t0 = time.perf_counter()
    while not cond():
        if time.perf_counter() - t0 > timeout:
            raise TimeoutError(f"waited {timeout:.0f} s for {what}")
        time.sleep(0.01)


def open_page(browser, teacher):
    page = browser.new_page(
        viewport={"width": 640, "height": 480}
    )  # small: software WebGL renders each move
    page.goto(teacher.url)
    page.get_by_text("environments:").wait_for(timeout=120_000)
    return page


def to_page(page, teacher):
    """World point -> page pixel, by the newest client's camera and the canvas's box, once the
    two agree (the panel docks beside the canvas after the page loads, resizing it)."""
    wait_until(lambda: teacher.server.get_clients(), "the page to connect")
    clients = teacher.server.get_clients()
    cam = clients[max(clients)].camera
    canvas = page.locator("canvas").first
    box = {}

    def settled() -> bool:
        box.update(canvas.bounding_box())
        return abs(cam.aspect - box["width"] / box["height"]) < 1e-3

    wait_until(settled, "the camera's aspect to match the canvas")

    def px(p):
        ((u, v),) = screen_points(
            cam.position, cam.wxyz, cam.fov, cam.aspect, np.asarray([p], dtype=np.float64)
        )
        return box["x"] + u * box["width"], box["y"] + v * box["height"]

    return px


def drag(page, px, teacher, points, reached, *, grab=(0.0, 0.0, 0.0), release: bool = True) -> None:
    """Press at ``points[0]`` (+ ``grab``), move through the others, each one waited for with
    ``reached(point)``, release (or not)."""
    pts = [np.asarray(p, dtype=np.float64) for p in points]
    off = np.asarray(grab, dtype=np.float64)
    for attempt in range(
        8
    ):  # a press can land before the page has drawn the control there (2 in 6 runs
        x0, y0 = px(pts[0] + off)  # missed it): release and press again, the camera read anew
        page.mouse.move(x0, y0)
        page.mouse.down()
        page.mouse.move(x0 + 4, y0)  # past viser's drag threshold: the drag starts
        try:
            wait_until(lambda: len(teacher.stroke) >= 1, "the drag to start", timeout=15.0)
            break
        except TimeoutError:
            page.mouse.up()
            if attempt == 7:
                raise
    for p in pts[1:]:
        page.mouse.move(*px(p + off), steps=2)
        wait_until(lambda: reached(p), f"the pointer at {p}")
    if release:
        done = teacher.strokes
        page.mouse.up()
        wait_until(lambda: teacher.strokes == done + 1, "the stroke to end")


def draw_particle(page, teacher, points, **kw) -> None:
    xy = [(x, y, 0.0) for x, y in points]
    near = lambda p: (
        bool(teacher.stroke) and float(np.abs(teacher.stroke[-1].numpy() - p[:2]).max()) < 0.06
    )
    drag(page, to_page(page, teacher), teacher, xy, near, **kw)


def click(page, name: str) -> None:
    page.get_by_role("button", name=name, exact=True).click()


def shows(page, text: str) -> None:
    page.wait_for_function("t => document.body.innerText.includes(t)", arg=text, timeout=120_000)


@pytest.mark.slow
def test_draw_keep_close_reopen_and_train(browser, tmp_path):
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    folder = tmp_path / "demos"
    proposals = torch.tensor([ENV_A, ENV_B, ENV_C], dtype=torch.float64)
    session = TeachSession(
        ParticleTeach(min_samples=5), folder, per_env=2, num_envs=2, proposals=proposals
    )
    teacher = Teacher(session, port=0)
    try:
        page = open_page(browser, teacher)
        shows(page, "this one: 0 of 2 kept")
        draw_particle(page, teacher, HOLE_A)  # through the hole
        shows(page, "steps: OK")
        assert (
            session.pending.quality.ok
            and page.get_by_role("button", name="Keep anyway").is_disabled()
        )
        click(page, "Keep")
        wait_until(lambda: session.kept == 1, "the first keep")
        draw_particle(page, teacher, WALL_A)  # into the wall
        shows(page, "enters the wall")
        assert session.pending.quality.flags == ("collides",)
        assert page.get_by_role("button", name="Keep", exact=True).is_disabled()
        page.screenshot(path=str(tmp_path / "flagged.png"))
        click(page, "Keep anyway")
        wait_until(lambda: session.kept == 2, "the insisted keep")
        shows(page, "environments: 1 of 2 done")  # the second environment came
        assert torch.equal(session.env, proposals[1])
        for k, path in ((3, HOLE_B), (4, HOLE_B2)):
            draw_particle(page, teacher, path)
            click(page, "Keep")
            wait_until(lambda: session.kept == k, f"keep {k}")
        shows(page, "target reached")
        strokes = teacher.strokes
        draw_particle(
            page, teacher, [(1.0, 5.0), (2.0, 5.0), (3.0, 5.1)], release=False
        )  # mid-stroke ...
        page.close()  # ... the page goes away: viser ends the drag for it
        wait_until(
            lambda: teacher.strokes == strokes + 1 and not teacher.server.get_clients(),
            "the disconnect",
        )
        assert read_demos(folder, PARTICLE_FORMAT).indices == [
            0,
            1,
            2,
            3,
        ]  # every kept one is on disk
        assert (
            session.kept == 4 and session.pending.raw.shape[0] >= 3
        )  # the stroke is shown, never written
        page = open_page(browser, teacher)  # reopened: the session goes on
        shows(page, "environments: 2 of 2 done")
        shows(page, "demonstrations kept: 4 (1 marked)")
        page.close()
    finally:
        teacher.close()
        torch.set_num_threads(threads)
    out = read_demos(folder, PARTICLE_FORMAT)
    assert out.indices == [0, 1, 2, 3] and [d.shape for d in out.demos] == [(100, 2)] * 4
    assert torch.equal(out.envs, proposals[:2].repeat_interleave(2, 0)) and read_marks(folder) == {
        1: ["collides"]
    }
    task = ParticleTeach().task
    assert task.collides(torch.stack(out.demos), out.envs).tolist() == [False, True, False, False]
    for d, drawn in zip(
        out.demos, (HOLE_A, WALL_A, HOLE_B, HOLE_B2)
    ):  # where the mouse pressed and let go
        assert float((d[[0, -1]] - torch.tensor(drawn)[[0, -1]]).abs().max()) < 0.03
    # the folder trains a small point_particle run
    m = point_particle.run(
        tmp_path / "run",
        optimizer={"beta": 20.0, "num_samples": 50, "max_iter": 30},
        plot=False,
        task={"demos": str(folder)},
        loop={"num_envs": 20, "batch_size": 20},
        test={"num_envs": 20},
        dynamic={"episodes": 0},
        dynamic_paper={"episodes": 0},
        baselines=["demos_only"],
        progress=False,
    )
    assert m["demos"] == {"source": str(folder), "count": 4, "envs": 2, "marked": 1}
    demo_rate, loop_rate = (
        m["baselines"]["demos_only"]["test"]["success_rate"],
        m["test"]["success_rate"],
    )
    print(
        f"taught 4 demonstrations in 2 environments: demonstrations-only success {demo_rate:.3f}, "
        f"loop success {loop_rate:.3f} on {m['test']['num_envs']} held-out environments"
    )
    assert 0.0 <= demo_rate <= 1.0 and 0.0 <= loop_rate <= 1.0 and m["loop"]["envs_tried"] == 20


@pytest.mark.slow
def test_the_arm_taught_by_dragging_its_hand(browser, tmp_path):
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    teach = ArmTeach(min_samples=4)
    env = torch.tensor([[0.56, 0.02, 0.70, 0.06]], dtype=torch.float64)
    session = TeachSession(teach, tmp_path / "arm", per_env=2, num_envs=1, proposals=env)
    teacher = Teacher(session, port=0)
    grab = (
        0.243 * 0.15,
        0.243 * 0.15,
        0.0,
    )  # the centre of the control's x-y square (drei's PivotControls)
    hand = np.asarray(teacher.follower.hand)
    at = lambda p: (
        float(np.abs(np.asarray(teacher.hand.position) - p).max()) < 0.012
    )  # a pixel is ~3 mm there
    try:
        page = open_page(browser, teacher)
        px = to_page(page, teacher)
        for dy in (0.16, 0.12):  # two demonstrations passing the can on the left
            way = [
                hand,
                hand + (0.06, 0.5 * dy, 0),
                hand + (0.16, dy, 0),
                hand + (0.26, 0.75 * dy, 0),
                np.array([0.70, 0.06, hand[2]]),
            ]
            drag(page, px, teacher, way, at, grab=grab)
            shows(page, "steps: OK")
            assert session.pending.quality.values["side"] == "left"
            click(page, "Keep")
            wait_until(
                lambda: session.pending is None and teacher.follower.hand[0] < 0.41,
                "the arm back at its start",
            )
        shows(page, "target reached")
        page.close()
    finally:
        teacher.close()
        torch.set_num_threads(threads)
    out = read_demos(session.folder, arm_demo_format(teach.task))
    assert len(out.demos) == 2 and torch.equal(out.envs, env.expand(2, 4))
    exp = arm_reach.prepare(
        optimizer={"name": "pro", "beta": 200.0, "max_iter": 2, "num_samples": 10},
        task={"demos": str(session.folder), "priors": 0},
        test={"num_envs": 2},
        dynamic={"episodes": 0},
    )
    assert exp.demo_labels.tolist() == [0, 0] and exp.describe()["demos"]["success_rate"] == 1.0
