"""Small suites written into a test's folder: a component that idles until SIGTERM."""

from __future__ import annotations

import textwrap
from pathlib import Path

#: writes its pid to ./pid, says it is ready, idles until SIGTERM
COMPONENT = """\
    import os, signal, threading
    open("pid", "w").write(str(os.getpid()))
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: threading.Thread(target=stop.set).start())
    print("component ready", flush=True)
    while not stop.wait(0.1):
        pass
    """


def quiet_suite(tmp_path: Path, test: str) -> Path:
    (tmp_path / "component.py").write_text(textwrap.dedent(COMPONENT))
    (tmp_path / "test_it.py").write_text(textwrap.dedent(test))
    path = tmp_path / "redline.toml"
    path.write_text(
        textwrap.dedent("""\
        name = "bad"
        tests = ["test_it.py"]
        [[component]]
        name = "quiet"
        command = ["python", "component.py"]
        ready = { log = "component ready" }
        """)
    )
    return path
