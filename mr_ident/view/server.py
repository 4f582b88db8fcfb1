# SPDX-License-Identifier: Apache-2.0
"""The view's HTTP server (standard library only): the page, its scripts, JSON, events.

``GET /``                the page (``page/index.html``)
``GET /app.js``          the page's script
``GET /plotly.min.js``   plotly.js from the installed ``plotly`` wheel (nothing is fetched
                         from the internet)
``GET /estimate.json``   the latest estimate (404 with ``{"error": ...}`` before the first);
                         ``?version=N`` one of the last 32 by its version
``GET /state.json``      estimate, health and the age of the estimate
``GET /events``          server-sent events: ``state`` with the state JSON at every change,
                         a comment every 10 s to keep the connection open
"""

from __future__ import annotations

import importlib.util
import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs

from ..errors import ConfigError
from .state import ViewState

PAGE = Path(__file__).resolve().parent / "page"
DEFAULT_PORT = 8765


def plotly_js() -> Path:
    """plotly.min.js of the installed plotly wheel; ConfigError naming the fix if absent."""
    spec = importlib.util.find_spec("plotly")
    if spec is None or not spec.submodule_search_locations:
        raise ConfigError("the view needs plotly.js from the plotly wheel: pip install plotly")
    path = Path(next(iter(spec.submodule_search_locations))) / "package_data" / "plotly.min.js"
    if not path.is_file():
        raise ConfigError(f"plotly is installed but has no {path}")
    return path


def _json(obj: Any) -> bytes:
    return json.dumps(obj, allow_nan=False, separators=(",", ":")).encode()


class _Handler(BaseHTTPRequestHandler):
    server: ViewServer

    def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 (http.server's name)
        pass  # quiet: the program prints its own one line

    def _send(self, code: int, body: bytes, ctype: str) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        state = self.server.state
        path = self.path.split("?", 1)[0]
        if path in ("/", "/index.html"):
            self._send(200, (PAGE / "index.html").read_bytes(), "text/html; charset=utf-8")
        elif path == "/app.js":
            self._send(200, (PAGE / "app.js").read_bytes(), "text/javascript; charset=utf-8")
        elif path == "/plotly.min.js":
            self._send(200, self.server.plotly, "text/javascript; charset=utf-8")
        elif path == "/estimate.json":
            query = parse_qs(self.path.partition("?")[2])
            try:
                version = int(query["version"][0]) if "version" in query else None
            except ValueError:
                self._send(400, _json({"error": "version must be an integer"}), "application/json")
                return
            est = state.estimate(version)
            if est is None:
                why = "no estimate yet" if version is None else f"version {version} not kept"
                self._send(404, _json({"error": why}), "application/json")
            else:
                self._send(200, _json(est), "application/json")
        elif path == "/state.json":
            self._send(200, _json(state.snapshot()), "application/json")
        elif path == "/events":
            self._events(state)
        else:
            self._send(404, _json({"error": f"no such page: {path}"}), "application/json")

    def _events(self, state: ViewState) -> None:
        self.send_response(200)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        seen = -1
        try:
            while not self.server.closing.is_set():
                snap = state.snapshot()
                if snap["version"] != seen:
                    seen = snap["version"]
                    self.wfile.write(b"event: state\ndata: " + _json(snap) + b"\n\n")
                else:
                    self.wfile.write(b": alive\n\n")
                self.wfile.flush()
                state.wait(seen, timeout=10.0)
        except (BrokenPipeError, ConnectionResetError):
            return  # the page went away


class ViewServer(ThreadingHTTPServer):
    """The HTTP server of one :class:`ViewState`, on its own thread after :meth:`start`."""

    daemon_threads = True

    def __init__(self, state: ViewState, host: str = "127.0.0.1", port: int = DEFAULT_PORT):
        self.state = state
        self.plotly = plotly_js().read_bytes()  # 4.8 MB, read once rather than per page
        self.closing = threading.Event()
        try:
            super().__init__((host, port), _Handler)
        except OSError as err:
            raise ConfigError(
                f"--port {port}: cannot listen on {host}:{port} ({err.strerror}); is another "
                "view running? choose another --port"
            ) from None
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        """The page's address."""
        host, port = self.server_address[:2]
        return f"http://{host!s}:{port}/"

    def start(self) -> ViewServer:
        """Serve on a daemon thread."""
        self._thread = threading.Thread(
            target=self.serve_forever, name="mr_ident-view", daemon=True
        )
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the socket (event streams end within a second)."""
        self.closing.set()
        self.state.wake()
        self.shutdown()
        self.server_close()
