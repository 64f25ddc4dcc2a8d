"""The demo's wait, against a small HTTP server answering as Redline's API would (a socket: not
a unit test)."""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

from redline.commands import demo


def test_the_demos_wait_ends_when_a_revision_was_cancelled():
    """A trial cancelled one revision during the demo: the wait went on for its 15 minutes."""
    answers = {
        "/api/v1/components/objectbuilder/revisions": [
            {"title": "r1", "state": "done"},
            {"title": "x", "state": "cancelled"},
        ],
        "/api/v1/components/objectbuilder/revisions/r1/verdict": {"state": "done"},
        "/api/v1/components/objectbuilder/revisions/x/verdict": {"state": "failed"},
    }

    class Server(BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 (http.server's name)
            body = json.dumps(answers[self.path]).encode()
            self.send_response(200)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Server)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        url = f"http://127.0.0.1:{server.server_port}"
        ended = demo.wait_for_results(url, lambda said: None, timeout=5)
    finally:
        server.shutdown()
    assert [r["state"] for r in ended] == ["done", "cancelled"]
