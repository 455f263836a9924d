"""The live viewer's play button on an arm run, caught by headless Chromium (docs/view.md's
``docs/img/view_arm_reach_live.png``; on demand, needs ``pip install -e ".[view,test]"`` and
``chromium`` on ``PATH``).

The run is served by :class:`protorch.view.server.Viewer` on a free port; the page opens with the
can at ``(can_x, --from-y)``; play starts; at ``--move-at`` seconds of the motion the can is moved
to ``--to-y`` (``Viewer.set_env``, what a drag of its handle calls); at ``--shot-at`` the play is
paused and the page is captured. Prints when the can moved, the side tracked and the switches.
``--still``: no play, the page as it opens with the can at ``(can_x, --from-y)`` (docs/view.md's
``docs/img/view_arm_reach.png``); prints the side chosen there.

    python benchmarks/view_live_shot.py RUN_DIR [--out live.png] [--from-y 0.02] [--to-y 0.12]
        [--move-at 0.8] [--shot-at 1.6] [--still]
"""

from __future__ import annotations

import argparse
import shutil
import time

import torch

from protorch.view.scene import open_run
from protorch.view.server import Viewer, info_markdown

CHROMIUM_ARGS = [
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--ignore-gpu-blocklist",
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--out", default="view_arm_reach_live.png")
    ap.add_argument("--from-y", type=float, default=0.02)
    ap.add_argument("--to-y", type=float, default=0.12)
    ap.add_argument("--move-at", type=float, default=0.8)
    ap.add_argument("--shot-at", type=float, default=1.6)
    ap.add_argument(
        "--still", action="store_true", help="no play: the page as it opens (the static view)"
    )
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright

    torch.set_num_threads(1)
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        raise SystemExit("no chromium on PATH (apt-get install -y chromium)")
    run = open_run(args.run)
    if run.kind != "arm":
        raise SystemExit(f"{args.run} is a {run.model.task_name} run; this shows the arm")
    viewer = Viewer(run, port=0, num_samples=16)
    y = [p.name for p in run.params].index("can_y")
    env = viewer.env.clone()
    env[y] = args.from_y
    viewer.set_env(env)
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1100, "height": 700})
        page.goto(viewer.url)
        page.get_by_text("mean trajectory:").wait_for(timeout=60_000)
        page.add_style_tag(
            content="[class*=Notification]{display:none !important}"
        )  # the software-WebGL notice
        page.wait_for_timeout(2000)
        if args.still:
            page.wait_for_timeout(1000)
            page.screenshot(path=args.out)
            browser.close()
            print(f"can at y {args.from_y}: the view's side {viewer.state.label}; wrote {args.out}")
            return
        player = viewer.player
        viewer.toggle_play()
        while player.t * player.dt < args.move_at and not player.done:
            time.sleep(0.001)
        env = viewer.env.clone()
        env[y] = args.to_y
        viewer.set_env(env, dragged=(0, 1))
        moved = player.t * player.dt
        while player.t * player.dt < args.shot_at and not player.done:
            time.sleep(0.001)
        viewer.toggle_play()  # paused: the page shows this instant
        viewer.wait_play(5.0)
        viewer.info.content = info_markdown(run, viewer.state, player)
        page.wait_for_timeout(3000)  # the last pose and panel reach the page
        page.screenshot(path=args.out)
        browser.close()
    print(
        f"can y {args.from_y} -> {args.to_y} at {moved:.2f} s; captured at "
        f"{player.t * player.dt:.2f} s: side "
        f"{player.label}, switches {player.switches}; wrote {args.out}"
    )


if __name__ == "__main__":
    main()
