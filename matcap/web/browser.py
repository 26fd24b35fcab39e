"""Headless Chromium settings shared by the browser tests (``tests/web``) and the README
screenshot script (``scripts/web_screenshot.py``): one copy of the flags that make WebGL2
work without a GPU."""

from __future__ import annotations

__all__ = ["CHROMIUM_ARGS"]

#: Headless Chromium without a GPU: WebGL2 through SwiftShader (software GL), which
#: recent Chromium enables only with --enable-unsafe-swiftshader; no network side traffic.
CHROMIUM_ARGS = (
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--use-gl=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
)
