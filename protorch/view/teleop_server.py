"""The teleoperation page's web server: a thin standard-library HTTP edge over
:class:`~protorch.view.teleop.TeleopSession`.

``GET /`` serves the page (``teleop_page.html``: the 3-D scene drawn on a canvas, the mouse,
keyboard and gamepad read in the browser); ``GET /api/geometry``, ``POST /api/start``
(``{"condition": ...}``) and ``POST /api/step`` (``{"wish": [7 numbers], "t": s}``) answer JSON; a
refused request answers 400 with ``{"error": "..."}``. One session, its calls serialised by a lock.
"""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from .teleop import TeleopSession

__all__ = ["TeleopServer", "PAGE"]

PAGE = Path(__file__).with_name("teleop_page.html")


class TeleopServer:
    """Serve ``session`` on ``host:port`` (port 0: a free one) in a background thread."""

    def __init__(
        self, session: TeleopSession, *, host: str = "127.0.0.1", port: int = 8080
    ) -> None:
        self.session = session
        self.lock = threading.Lock()
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args) -> None:  # quiet: the page polls at 50 Hz
                pass

            def _send(self, code: int, body: bytes, kind: str) -> None:
                self.send_response(code)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def _json(self, code: int, obj) -> None:
                self._send(code, json.dumps(obj).encode(), "application/json")

            def do_GET(self) -> None:  # noqa: N802 (the standard library's name)
                if self.path in ("/", "/index.html"):
                    self._send(200, PAGE.read_bytes(), "text/html; charset=utf-8")
                elif self.path == "/api/geometry":
                    with server.lock:
                        self._json(200, server.session.geometry())
                else:
                    self._json(404, {"error": f"no page {self.path}"})

            def do_POST(self) -> None:  # noqa: N802
                try:
                    n = int(self.headers.get("Content-Length") or 0)
                    body = json.loads(self.rfile.read(n) or b"{}")
                    with server.lock:
                        if self.path == "/api/start":
                            out = server.session.start(body.get("condition"))
                        elif self.path == "/api/step":
                            out = server.session.step(body["wish"], float(body["t"]))
                        else:
                            return self._json(404, {"error": f"no endpoint {self.path}"})
                except (ValueError, KeyError, TypeError) as exc:
                    return self._json(400, {"error": str(exc)})
                self._json(200, out)

        self.httpd = ThreadingHTTPServer((host, port), Handler)
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    @property
    def url(self) -> str:
        host, port = self.httpd.server_address[:2]
        return f"http://{host}:{port}/"

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


def teleop_main(argv) -> int:
    """``python -m protorch.view teleop RUN [--study N] [--conditions none,fixed,adaptive] [--out
    DIR]``."""
    import argparse
    import time

    ap = argparse.ArgumentParser(
        prog="protorch view teleop",
        description="drive the beam through the moving window, guided by RUN's map",
    )
    ap.add_argument("run_dir", help="a finished experiment=teleop_window run")
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument(
        "--port", type=int, default=8080, help="port (default 8080; 0 picks a free one)"
    )
    ap.add_argument(
        "--study", type=int, default=0, help="trials per condition, counterbalanced (0: free mode)"
    )
    ap.add_argument(
        "--conditions", default="none,fixed,adaptive", help="comma-separated (default all three)"
    )
    ap.add_argument("--out", help="where trials.csv and the raw poses go (default RUN/study)")
    ap.add_argument(
        "--time-limit", type=float, default=30.0, help="s a trial may last (default 30)"
    )
    args = ap.parse_args(argv)
    try:
        session = TeleopSession(
            args.run_dir,
            conditions=[c for c in args.conditions.split(",") if c],
            study=args.study,
            out=args.out,
            time_limit=args.time_limit,
        )
    except (FileNotFoundError, ValueError) as exc:
        print(f"protorch view teleop: {exc}", flush=True)
        return 1
    server = TeleopServer(session, host=args.host, port=args.port)
    print(
        f"protorch view: teleoperation of {Path(args.run_dir).resolve()} at {server.url}; trials "
        "are written to "
        f"{session.out.resolve()}  (Ctrl-C stops)",
        flush=True,
    )
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        server.close()
    return 0
