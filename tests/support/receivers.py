"""Real receivers of what Redline sends: an HTTP server that records every request (and can be
told to fail or be slow, path by path), and an SMTP server (aiosmtpd) that requires STARTTLS and a
login, with a certificate from a test CA (trustme), and can be told to refuse or be slow, command
by command."""

from __future__ import annotations

import asyncio
import ssl
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from email import message_from_bytes, policy
from email.message import EmailMessage
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import httpx
from redline.agent.network import free_port


@dataclass
class Request:
    method: str
    path: str
    headers: httpx.Headers  # case-insensitive, as HTTP's are
    body: bytes


@dataclass
class Receiver:
    """``answers[path]``: statuses given in turn (then 200); ``delays[path]``: seconds to wait;
    ``bodies[path]``: the body a success answers with (else ``{"ok": true}``)."""

    url: str
    requests: list[Request] = field(default_factory=list)
    answers: dict[str, list[int]] = field(default_factory=dict)
    delays: dict[str, float] = field(default_factory=dict)
    bodies: dict[str, bytes] = field(default_factory=dict)

    def to(self, path: str) -> list[Request]:
        return [r for r in self.requests if r.path == path]


@contextmanager
def http_receiver() -> Iterator[Receiver]:
    lock = threading.Lock()
    receiver = Receiver(url="")

    class Handler(BaseHTTPRequestHandler):
        def _answer(self) -> None:
            body = self.rfile.read(int(self.headers.get("Content-Length") or 0))
            with lock:  # recorded as it arrives, answered after the delay
                receiver.requests.append(
                    Request(self.command, self.path, httpx.Headers(self.headers.items()), body)
                )
                queue = receiver.answers.get(self.path)
                status = queue.pop(0) if queue else 200
            time.sleep(receiver.delays.get(self.path, 0.0))
            try:
                self.send_response(status)
                self.send_header("Content-Type", "application/json")
                self.end_headers()
                ok = receiver.bodies.get(self.path, b'{"ok": true}')
                self.wfile.write(ok if status < 300 else b'{"error": "down"}')
            except (BrokenPipeError, ConnectionResetError):
                pass  # the caller gave up (a timeout): what a slow receiver sees

        do_POST = do_PUT = _answer

        def log_message(self, *args: object) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    server.daemon_threads = True
    receiver.url = f"http://127.0.0.1:{server.server_address[1]}"
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield receiver
    finally:
        server.shutdown()
        server.server_close()


@dataclass
class Mailbox:
    """``messages``: the mails the server took (answered 250); ``arrived``: every mail whose
    content came in, taken or not. ``answers[command]`` ("RCPT" or "DATA"): replies given in
    turn (then "250 OK"); ``delays[command]``: seconds to wait before replying (the mail is in
    ``arrived`` already while a DATA reply waits)."""

    host: str
    port: int
    ca_file: Path
    user: str
    password: str
    messages: list[EmailMessage] = field(default_factory=list)
    recipients: list[list[str]] = field(default_factory=list)
    arrived: list[EmailMessage] = field(default_factory=list)
    answers: dict[str, list[str]] = field(default_factory=dict)
    delays: dict[str, float] = field(default_factory=dict)

    async def reply(self, command: str) -> str:
        queue = self.answers.get(command)
        answer = queue.pop(0) if queue else "250 OK"
        await asyncio.sleep(self.delays.get(command, 0.0))  # cancelled if the client goes
        return answer


@contextmanager
def smtp_server(folder: Path, user: str = "redline", password: str = "s3cret") -> Iterator[Mailbox]:
    """An SMTP server on 127.0.0.1 that refuses to take a login or a mail before STARTTLS."""
    import trustme
    from aiosmtpd.controller import Controller
    from aiosmtpd.smtp import AuthResult, LoginPassword

    authority = trustme.CA()
    tls = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    authority.issue_cert("127.0.0.1", "localhost").configure_cert(tls)
    ca_file = folder / "smtp-ca.pem"
    authority.cert_pem.write_to_path(str(ca_file))
    box = Mailbox("127.0.0.1", free_port(), ca_file, user, password)

    class Handler:
        async def handle_RCPT(self, server, session, envelope, address, options):  # noqa: N802
            answer = await box.reply("RCPT")
            if answer.startswith("250"):
                envelope.rcpt_tos.append(address)  # aiosmtpd leaves it to a handler that has one
            return answer

        async def handle_DATA(self, server, session, envelope):  # noqa: N802 (aiosmtpd's name)
            mail = message_from_bytes(envelope.content, policy=policy.default)  # type: ignore[arg-type]
            box.arrived.append(mail)
            answer = await box.reply("DATA")
            if answer.startswith("250"):
                box.messages.append(mail)
                box.recipients.append(list(envelope.rcpt_tos))
            return answer

    def authenticate(server, session, envelope, mechanism, auth_data):
        ok = isinstance(auth_data, LoginPassword) and (
            auth_data.login.decode(),
            auth_data.password.decode(),
        ) == (user, password)
        return AuthResult(success=ok)

    controller = Controller(
        Handler(),
        hostname="127.0.0.1",
        port=box.port,
        tls_context=tls,
        require_starttls=True,
        authenticator=authenticate,
        auth_required=True,
    )
    controller.start()
    try:
        yield box
    finally:
        controller.stop()
