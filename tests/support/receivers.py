"""Real receivers of what Redline sends: an HTTP server that records every request (and can be
told to fail or be slow, path by path), and an SMTP server (aiosmtpd) that requires STARTTLS and a
login, with a certificate from a test CA (trustme), and can be told to refuse or be slow, command
by command."""

from __future__ import annotations

import asyncio
import ssl
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from email import message_from_bytes, policy
from email.message import EmailMessage
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qsl, urlsplit

import httpx
from redline.agent.network import free_port


class Quiet(BaseHTTPRequestHandler):
    def log_message(self, *args: object) -> None:
        pass


@contextmanager
def serving(handler: type[BaseHTTPRequestHandler]) -> Iterator[str]:
    """An HTTP server of ``handler`` on a free port of 127.0.0.1, on threads; yields its URL."""
    server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    server.daemon_threads = True
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


@dataclass
class Request:
    method: str
    path: str
    headers: httpx.Headers  # case-insensitive, as HTTP's are
    body: bytes


@dataclass
class Receiver:
    """``answers[path]``: statuses given in turn (then 200); ``delays[path]``: seconds to wait;
    ``bodies[path]``: the body a success answers with (else ``{"ok": true}``); ``drips[path]``:
    seconds between the answer's bytes (a receiver trickling its answer)."""

    url: str
    requests: list[Request] = field(default_factory=list)
    answers: dict[str, list[int]] = field(default_factory=dict)
    delays: dict[str, float] = field(default_factory=dict)
    bodies: dict[str, bytes] = field(default_factory=dict)
    drips: dict[str, float] = field(default_factory=dict)

    def to(self, path: str) -> list[Request]:
        return [r for r in self.requests if r.path == path]


@contextmanager
def http_receiver() -> Iterator[Receiver]:
    lock = threading.Lock()
    receiver = Receiver(url="")

    class Handler(Quiet):
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
                answer = ok if status < 300 else b'{"error": "down"}'
                drip = receiver.drips.get(self.path)
                for start in range(0, len(answer), 1 if drip else len(answer)):
                    self.wfile.write(answer[start : start + 1] if drip else answer)
                    self.wfile.flush()
                    time.sleep(drip or 0.0)
            except (BrokenPipeError, ConnectionResetError):
                pass  # the caller gave up (a timeout): what a slow receiver sees

        do_POST = do_PUT = _answer

    with serving(Handler) as url:
        receiver.url = url
        yield receiver


@dataclass
class Mailbox:
    """``messages``: the mails the server took (answered 250); ``arrived``: every mail whose
    content came in, taken or not. ``answers[command]`` ("RCPT", "DATA" or "QUIT"): replies
    given in turn (then "250 OK", or QUIT's "221 Bye"); ``delays[command]``: seconds to wait
    before replying (the mail is in ``arrived`` already while a DATA reply waits)."""

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

        async def handle_QUIT(self, server, session, envelope):  # noqa: N802
            queue = box.answers.get("QUIT")
            return queue.pop(0) if queue else "221 Bye"

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


@dataclass
class Proxy:
    """``answers[suffix]``: statuses given in turn (then forwarded) to GETs whose path, without
    its query, ends with ``suffix``; ``seen``: every path asked, with its query; ``dropped``:
    query parameters left out when forwarding (a server from before them); ``before[suffix]``:
    called before such a GET is forwarded (the server's state changing between requests)."""

    url: str
    answers: dict[str, list[int]] = field(default_factory=dict)
    seen: list[str] = field(default_factory=list)
    dropped: set[str] = field(default_factory=set)
    before: dict[str, Callable[[], None]] = field(default_factory=dict)


@contextmanager
def flaky_proxy(upstream: str) -> Iterator[Proxy]:
    """A reverse proxy in front of ``upstream`` that answers as told before forwarding (a
    proxy's 502 while its server restarts)."""
    lock = threading.Lock()
    proxy = Proxy(url="")

    class Handler(Quiet):
        def do_GET(self) -> None:  # noqa: N802 (http.server's name)
            with lock:
                proxy.seen.append(self.path)
                path = self.path.split("?", 1)[0]
                queue = next((q for s, q in proxy.answers.items() if path.endswith(s)), None)
                status = queue.pop(0) if queue else None
            if status is None:
                for suffix, call in proxy.before.items():
                    if path.endswith(suffix):
                        call()
                query = [(k, v) for k, v in parse_qsl(urlsplit(self.path).query)
                         if k not in proxy.dropped]  # fmt: skip
                headers = {"Authorization": self.headers.get("Authorization", "")}
                answer = httpx.get(upstream + path, params=query, headers=headers, timeout=30)
                status, body = answer.status_code, answer.content
                kind = answer.headers.get("Content-Type", "text/plain")
            else:
                body, kind = b"<html>Bad Gateway</html>", "text/html"
            self.send_response(status)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

    with serving(Handler) as url:
        proxy.url = url
        yield proxy
