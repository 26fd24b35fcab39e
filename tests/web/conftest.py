"""Fixtures of the web app's tests: a real ``relight serve`` process on a free port with a
temporary data folder, and headless Chromium from Debian's package driven by Playwright.

The browser tests skip, saying why, only where no Chromium binary exists (CI installs
Debian's ``chromium``; ``.ci/run``). Playwright's own browser download is never used.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from matcap.web.browser import CHROMIUM_ARGS

REPO = Path(__file__).resolve().parents[2]
#: Debian's chromium first, then other usual names.
CHROMIUM_CANDIDATES = ("/usr/bin/chromium", "/usr/bin/chromium-browser", "/usr/bin/google-chrome")
#: Seconds a server gets to answer its first request (imports torch and the app).
SERVER_START_S = 120
#: Upload limit of the test server, MB: small, so the too-large test sends little.
TEST_UPLOAD_MB = 1


def chromium_path() -> str | None:
    for candidate in CHROMIUM_CANDIDATES:
        if os.access(candidate, os.X_OK):
            return candidate
    found = shutil.which("chromium")
    return found


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """A ``relight serve`` process (``python -m matcap.cli serve``)."""

    def __init__(self, data: Path, *extra: str):
        self.port = free_port()
        self.data = data
        self.url = f"http://127.0.0.1:{self.port}"
        env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONUNBUFFERED="1")
        self.log = open(data.parent / f"server-{self.port}.log", "w")  # noqa: SIM115 (closed in stop)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "matcap.cli", "serve", "--port", str(self.port), "--data", str(data), *extra],
            stdout=self.log,
            stderr=subprocess.STDOUT,
            cwd=REPO,
            env=env,
            start_new_session=True,
        )
        deadline = time.monotonic() + SERVER_START_S
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited: {(data.parent / f'server-{self.port}.log').read_text()}")
            try:
                self.get_json("/api/options")
                return
            except (urllib.error.URLError, ConnectionError):
                if time.monotonic() > deadline:
                    self.stop()
                    raise RuntimeError("server did not start") from None
                time.sleep(0.3)

    def get(self, path: str) -> tuple[int, bytes]:
        try:
            with urllib.request.urlopen(self.url + path, timeout=30) as res:
                return res.status, res.read()
        except urllib.error.HTTPError as err:
            return err.code, err.read()

    def get_json(self, path: str):
        status, body = self.get(path)
        return json.loads(body) if status == 200 else {"status": status, **json.loads(body)}

    def post_photo(self, data: bytes, name: str = "photo.png", **fields) -> tuple[int, dict]:
        """A multipart POST /api/jobs, as a browser's FormData sends it."""
        boundary = "----relighttest" + os.urandom(8).hex()
        parts = []
        for key, value in fields.items():
            parts.append(f'--{boundary}\r\nContent-Disposition: form-data; name="{key}"\r\n\r\n{value}\r\n'.encode())
        parts.append(
            f'--{boundary}\r\nContent-Disposition: form-data; name="photo"; filename="{name}"\r\n'
            "Content-Type: application/octet-stream\r\n\r\n".encode()
            + data
            + b"\r\n"
        )
        body = b"".join(parts) + f"--{boundary}--\r\n".encode()
        request = urllib.request.Request(
            self.url + "/api/jobs",
            data=body,
            method="POST",
            headers={"Content-Type": f"multipart/form-data; boundary={boundary}"},
        )
        try:
            with urllib.request.urlopen(request, timeout=60) as res:
                return res.status, json.loads(res.read())
        except urllib.error.HTTPError as err:
            return err.code, json.loads(err.read())

    def wait(self, job_id: str, timeout: float) -> dict:
        deadline = time.monotonic() + timeout
        while True:
            status = self.get_json(f"/api/jobs/{job_id}")
            if status.get("final") or time.monotonic() > deadline:
                return status
            time.sleep(0.5)

    def stop(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, 15)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, 9)
                self.proc.wait()
        self.log.close()


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    root = tmp_path_factory.mktemp("web")
    srv = Server(root / "data", "--max-upload-mb", str(TEST_UPLOAD_MB))
    srv.upload_mb = TEST_UPLOAD_MB
    yield srv
    srv.stop()


@pytest.fixture
def make_server():
    """``Server`` itself, for a test that starts one with flags of its own (and stops it)."""
    return Server


@pytest.fixture(scope="module")
def browser():
    path = chromium_path()
    if path is None:
        pytest.skip("no Chromium binary (apt-get install -y chromium): the browser tests need one")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        chromium = pw.chromium.launch(executable_path=path, args=list(CHROMIUM_ARGS), headless=True)
        yield chromium
        chromium.close()


@pytest.fixture
def page(browser):
    context = browser.new_context(viewport={"width": 1280, "height": 900}, accept_downloads=True)
    pg = context.new_page()
    yield pg
    context.close()
