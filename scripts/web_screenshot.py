"""A screenshot of ``relight serve`` with a finished capture (README "Web app").

    .venv/bin/python scripts/web_screenshot.py [--out results/webapp/screenshot.png] [--size 128]

Starts the server on a free port with a temporary data folder, drops a flash photo of
the built-in procedural material (``builtin_photo``, ``--size`` pixels, 8-bit PNG) on the
page in headless Chromium (Debian's ``/usr/bin/chromium``, the flags of the browser
tests), runs the capture with the page's defaults (diffusion relighter, 7 relit views,
100 refinement steps), moves the viewer's light off the flash, and saves the page.
"""

from __future__ import annotations

import argparse
import io
import os
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Sequence
from pathlib import Path

from matcap.web.browser import CHROMIUM_ARGS

REPO = Path(__file__).resolve().parents[1]
DEFAULT_OUT = REPO / "results" / "webapp" / "screenshot.png"
CHROMIUM = "/usr/bin/chromium"
#: Seconds the capture may take (a default capture of a 128 px photo on a CPU).
CAPTURE_TIMEOUT_S = 900


def photo_png(size: int) -> bytes:
    import numpy as np
    from PIL import Image

    from kernels.tonemap import tonemap
    from matcap.capture import builtin_photo

    photo = builtin_photo("", size=size)
    codes = (tonemap(photo.image).permute(1, 2, 0).numpy() * 255.0).round().astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(codes).save(buf, format="PNG")
    return buf.getvalue()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--size", type=int, default=128, help="photo side, pixels")
    args = parser.parse_args(argv)
    from playwright.sync_api import sync_playwright

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"http://127.0.0.1:{port}"
    with tempfile.TemporaryDirectory() as tmp:
        server = subprocess.Popen(
            [sys.executable, "-m", "matcap.cli", "serve", "--port", str(port), "--data", str(Path(tmp) / "data")],
            cwd=REPO,
            start_new_session=True,
        )
        try:
            for _ in range(600):
                try:
                    urllib.request.urlopen(url + "/api/options", timeout=5).close()
                    break
                except OSError:
                    time.sleep(0.2)
            with sync_playwright() as pw:
                browser = pw.chromium.launch(executable_path=CHROMIUM, args=list(CHROMIUM_ARGS), headless=True)
                page = browser.new_page(viewport={"width": 1280, "height": 900})
                page.goto(url)
                page.wait_for_selector("#relighter option", state="attached")
                photo = {"name": "builtin.png", "mimeType": "image/png", "buffer": photo_png(args.size)}
                page.set_input_files("#photo", files=[photo])
                page.wait_for_selector('#jobs li[data-state="done"]', timeout=CAPTURE_TIMEOUT_S * 1000)
                page.wait_for_function("document.body.dataset.viewerJob", timeout=60_000)
                page.evaluate("window.relightApp.viewer.setLight([1.6, 1.2, 2.5])")
                page.wait_for_timeout(500)
                args.out.parent.mkdir(parents=True, exist_ok=True)
                page.screenshot(path=str(args.out), full_page=True)
                browser.close()
        finally:
            os.killpg(server.pid, 15)
            server.wait(30)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1024:.0f} KB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
