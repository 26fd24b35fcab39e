"""``relight serve``: the local web app (``matcap.web.app``) on uvicorn."""

from __future__ import annotations

import argparse
from pathlib import Path

from matcap.errors import UsageError

__all__ = ["add_parser", "run", "DEFAULT_HOST", "DEFAULT_PORT", "DEFAULT_DATA"]

#: Loopback only: the app has no accounts, so other machines must not reach it unless
#: the user says so with --host.
DEFAULT_HOST = "127.0.0.1"
#: The port Gradio demos use, so a user of the field's demos finds it where expected.
DEFAULT_PORT = 7860
#: Jobs folder, relative to the working directory.
DEFAULT_DATA = Path("relight-web")


def add_parser(sub: argparse._SubParsersAction) -> None:
    from matcap.web.jobs import DEFAULT_MAX_UPLOAD_MB

    p = sub.add_parser(
        "serve",
        help="local web app: drop a photo, watch the capture, get the maps and a live relightable preview",
        description="Serve a web page that runs `relight capture` on uploaded photos (PNG, JPEG, EXR): "
        "progress while it runs, the relit views with their lights, the four maps, a WebGL2 viewer "
        "that relights the maps under a light you drag (the same BRDF and tone map as kernels.render), "
        "and downloads of the output folder (zip) and the .glb. Jobs run one at a time (--workers), "
        "each in its own folder under --data; results survive a reload and a restart.",
    )
    p.add_argument("--host", default=DEFAULT_HOST, help=f"address to listen on (default {DEFAULT_HOST}: this machine)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT}; 0: any free one)")
    p.add_argument("--workers", type=int, default=1, help="captures running at the same time (default 1)")
    p.add_argument("--queue", type=int, default=16, metavar="N", help="photos waiting at most (default 16)")
    p.add_argument("--data", type=Path, default=DEFAULT_DATA, help=f"jobs folder (default ./{DEFAULT_DATA})")
    p.add_argument(
        "--max-upload-mb",
        type=float,
        default=DEFAULT_MAX_UPLOAD_MB,
        help=f"largest photo accepted, MB (default {DEFAULT_MAX_UPLOAD_MB})",
    )
    p.set_defaults(run=run)


def run(args) -> int:
    try:
        import uvicorn

        from matcap.web.app import create_app
    except ImportError as err:
        raise UsageError(f"the web app needs its extra: pip install 'dgrsise[web]' ({err})") from None
    for flag, value, low in (("--workers", args.workers, 1), ("--queue", args.queue, 1), ("--port", args.port, 0)):
        if value < low:
            raise UsageError(f"{flag} must be >= {low}, got {value}")
    if not args.max_upload_mb > 0:
        raise UsageError(f"--max-upload-mb must be positive, got {args.max_upload_mb}")
    app = create_app(args.data, workers=args.workers, max_pending=args.queue, max_upload_mb=args.max_upload_mb)
    print(f"relight serve: jobs in {args.data.resolve()}; open http://{args.host}:{args.port}/", flush=True)
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning")
    return 0
