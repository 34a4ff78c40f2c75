"""``lunaralbedo view``: serve a web site folder on localhost (standard library HTTP server)."""
from __future__ import annotations

import functools
import http.server
from pathlib import Path


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    """Static files only; no per-request log lines on the terminal."""

    def log_message(self, format, *args):  # noqa: A002 (the base class's signature)
        pass


def make_server(site: str | Path, host: str = "127.0.0.1", port: int = 8000) -> http.server.ThreadingHTTPServer:
    """A threading HTTP server of ``site`` bound to ``host:port`` (port 0: any free port)."""
    handler = functools.partial(_QuietHandler, directory=str(site))
    return http.server.ThreadingHTTPServer((host, port), handler)


def url_of(server: http.server.HTTPServer) -> str:
    host, port = server.server_address[:2]
    return f"http://{host}:{port}/index.html"
