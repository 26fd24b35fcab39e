"""The web app: a FastAPI application serving one hand-written page and a JSON API.

Endpoints (``{id}``: a job id, ``jobs.JOB_ID``; any other id is a 404):

    GET  /                               the page (static/index.html)
    GET  /static/{file}                  its script, viewer and style (no CDN, no network)
    GET  /api/options                    relighters, defaults and limits for the form
    POST /api/jobs                       multipart: ``photo`` (PNG/JPEG/EXR) + relit, relighter,
                                         refine, fov -> 201 the job's status; 400 a bad photo or
                                         setting, 413 too large, 503 queue full ({"error": ...})
    GET  /api/jobs/{id}                  status: state, stage, percent, queue position, error;
                                         when done, the result (files, lights, viewer settings)
    POST /api/jobs/{id}/cancel           cancel a waiting or running job
    GET  /api/jobs/{id}/files/{path}     a file of the output folder (only inside it)
    GET  /api/jobs/{id}/maps.bin         the four maps as float32 for the WebGL viewer
    GET  /api/jobs/{id}/download.zip     the whole output folder
    GET  /api/jobs/{id}/material.glb     the glTF binary

Uploads are limited twice: ``UploadLimit`` refuses a request whose body is longer than the
limit (declared or counted) before the form is parsed, and the handler checks the file's
own size. A photo is decoded with ``materials.io.read_photo`` (the reader the CLI uses)
before it becomes a job, so a photo the page accepts is one the capture reads.
"""

from __future__ import annotations

import json
import os
import pkgutil
import shutil
from contextlib import asynccontextmanager
from pathlib import Path

import numpy as np
from fastapi import FastAPI, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.datastructures import UploadFile

from matcap.web.jobs import DEFAULT_MAX_UPLOAD_MB, FINAL_STATES, CaptureOptions, JobQueue, JobStore, QueueFull

__all__ = ["create_app", "UploadLimit", "known_relighters", "photo_plane", "viewer_settings", "maps_bytes", "MAPS"]

STATIC = Path(__file__).parent / "static"
#: Bytes allowed on top of the file for the multipart framing and the form's fields.
_FORM_OVERHEAD = 64 * 1024
#: Bytes per read while copying an upload to disk.
_CHUNK = 1 << 20
#: The viewer's maps, in the order of maps.bin, with their channel counts.
MAPS = (("diffuse", 3), ("normal", 3), ("roughness", 1), ("specular", 3))
#: Files of the output folder the page shows (the file endpoint serves any file inside it).
_MAP_PNGS = ("diffuse", "normal", "roughness", "specular")


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


class UploadLimit:
    """ASGI wrapper: a POST whose body exceeds ``limit`` bytes gets a 413 JSON answer.

    A declared Content-Length over the limit is refused before anything is read; an
    undeclared (chunked) body is counted, and when it passes the limit the app sees the
    client disconnect and its answer is replaced by the 413.
    """

    def __init__(self, app, limit: int, message: str):
        self.app = app
        self.limit = limit
        self.message = message

    async def _refuse(self, send) -> None:
        body = json.dumps({"error": self.message}).encode()
        headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
        await send({"type": "http.response.start", "status": 413, "headers": headers})
        await send({"type": "http.response.body", "body": body})

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope["method"] != "POST":
            return await self.app(scope, receive, send)
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.limit:
            return await self._refuse(send)
        seen, over, started = 0, False, False

        async def counted():
            nonlocal seen, over
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.limit:
                    over = True
                    return {"type": "http.disconnect"}
            return message

        async def guarded_send(message):
            nonlocal started
            if over:
                return  # the app's answer to a cut-off body is replaced by the 413
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counted, guarded_send)
        except Exception:
            if not over:
                raise
        if over and not started:
            await self._refuse(send)


def known_relighters() -> list[str]:
    """Registered relighter names plus the ``relight`` subpackages whose ``__init__`` calls
    ``register_relighter`` (plugins register under their package's name on import; their
    source is read, not imported, which would load diffusers into the server)."""
    import relight
    from matcap.estimator_relighter import register
    from relight.interface import relighter_names

    register()
    names = relighter_names()
    for info in pkgutil.iter_modules(relight.__path__):
        if not info.ispkg or info.name in names:
            continue
        init = Path(info.module_finder.path) / info.name / "__init__.py"
        try:
            registers = "register_relighter(" in init.read_text(encoding="utf-8")
        except OSError:
            registers = False
        if registers:  # a plugin (its __init__ registers it), not a library subpackage
            names.append(info.name)
    return names


def _number(form, name: str, kind, default):
    text = form.get(name)
    if text is None or (isinstance(text, str) and not text.strip()):
        return default
    if not isinstance(text, str):
        raise ValueError(f"{name} must be a number")
    try:
        return kind(text.strip())
    except ValueError:
        raise ValueError(f"{name} must be {'a whole number' if kind is int else 'a number'}, got {text!r}") from None


def create_app(
    data_dir: str | os.PathLike,
    *,
    workers: int = 1,
    max_pending: int = 16,
    max_upload_mb: float = DEFAULT_MAX_UPLOAD_MB,
    relighters: list[str] | None = None,
    job_env: dict | None = None,
):
    """The ASGI application (FastAPI inside ``UploadLimit``).

    Args:
        data_dir: where the jobs live (created); jobs found there are served and the
            unfinished ones re-queued.
        workers: captures running at the same time.
        max_pending: jobs waiting at most (then 503).
        max_upload_mb: upload limit, megabytes (10^6 bytes).
        relighters: names offered (default ``known_relighters()``).
        job_env: environment of the capture processes (default the server's).
    """
    store = JobStore(data_dir)
    jobs = JobQueue(store, workers=workers, max_pending=max_pending, env=job_env)
    limit = int(max_upload_mb * 1e6)
    names = relighters if relighters is not None else known_relighters()
    too_large = f"the file is larger than the upload limit of {max_upload_mb:g} MB"

    @asynccontextmanager
    async def lifespan(app):
        jobs.start()
        yield
        await run_in_threadpool(jobs.stop)

    app = FastAPI(title="relight", lifespan=lifespan, docs_url=None, redoc_url=None, openapi_url=None)
    app.state.store, app.state.jobs = store, jobs
    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    @app.get("/")
    def index():
        return FileResponse(STATIC / "index.html", media_type="text/html")

    @app.get("/api/options")
    def options():
        defaults = CaptureOptions()
        return {
            "relighters": names,
            "defaults": {"relit": defaults.relit, "relighter": defaults.relighter, "refine": defaults.refine},
            "limits": {
                "relit": CaptureOptions.MAX_RELIT,
                "refine": CaptureOptions.MAX_REFINE,
                "upload_bytes": limit,
                "formats": ["png", "jpeg", "exr"],
            },
        }

    def accept(source, filename: str | None, opts: CaptureOptions) -> dict:
        """Copy an upload to tmp/, check it is a photo, make the job (or leave nothing)."""
        from materials.io.errors import FormatError
        from materials.io.photo import read_photo

        tmp = store.new_temp(".upload")
        try:
            size = 0
            with open(tmp, "wb") as f:
                while chunk := source.read(_CHUNK):
                    size += len(chunk)
                    if size > limit:
                        return {"status": 413, "error": too_large}
                    f.write(chunk)
            if size == 0:
                return {"status": 400, "error": "the file is empty"}
            try:
                photo = read_photo(tmp)
            except FormatError as err:
                return {"status": 400, "error": f"{filename or 'the file'}: {err.problem}"}
            except Exception as err:  # a decoder's own error on a damaged file
                return {"status": 400, "error": f"{filename or 'the file'}: cannot be read as a photo ({err})"}
            job = store.create(tmp, photo.format, filename or "photo", opts)
            try:
                jobs.submit(job.id)
            except QueueFull as err:
                shutil.rmtree(store.folder(job.id), ignore_errors=True)
                return {"status": 503, "error": str(err)}
            return {"status": 201, "job": job.id}
        finally:
            tmp.unlink(missing_ok=True)

    @app.post("/api/jobs")
    async def submit(request: Request):
        try:
            form = await request.form(max_files=1, max_fields=16)
        except Exception as err:
            return _error(400, f"the upload could not be read as a form: {err}")
        upload = form.get("photo")
        if not isinstance(upload, UploadFile):
            return _error(400, "no photo in the upload (the form field 'photo')")
        try:
            fov = _number(form, "fov", float, None)
            opts = CaptureOptions(
                relit=_number(form, "relit", int, CaptureOptions.relit),
                relighter=str(form.get("relighter") or CaptureOptions.relighter).strip(),
                refine=_number(form, "refine", int, CaptureOptions.refine),
                fov=fov,
            ).check(names)
        except ValueError as err:
            return _error(400, str(err))
        result = await run_in_threadpool(accept, upload.file, upload.filename, opts)
        await upload.close()
        if "error" in result:
            return _error(result["status"], result["error"])
        return JSONResponse(status_payload(result["job"]), status_code=201)

    def status_payload(job_id: str) -> dict:
        job = store.read(job_id)
        data = job.to_dict()
        data["queue_position"] = jobs.position(job_id)
        data["final"] = job.state in FINAL_STATES
        if job.state == "done":
            data["result"] = result_payload(job_id)
        return data

    def result_payload(job_id: str) -> dict:
        out = store.folder(job_id) / "out"
        prov = json.loads((out / "provenance.json").read_text(encoding="utf-8"))
        scene, frame = prov["scene"], prov["frame"]
        base = f"/api/jobs/{job_id}"

        def url(rel: str) -> str | None:
            return f"{base}/files/{rel}" if (out / rel).is_file() else None

        relit = [
            {"url": url(f"relit/relit_{k:02d}.png"), "light": light} for k, light in enumerate(scene["relit_light_pos"])
        ]
        renders = [
            {"url": url(f"renders/view_{k:02d}.png"), "light": light}
            for k, light in enumerate(scene["render_light_pos"])
        ]
        return {
            "preview": url("preview.png"),
            "photo_plane": photo_plane(frame),
            "camera": scene["camera_pos"],
            "relit": relit,
            "renders": renders,
            "maps": {name: url(f"material/{name}.png") for name in _MAP_PNGS},
            "zip": f"{base}/download.zip",
            "glb": f"{base}/material.glb" if (out / "material" / "material.glb").is_file() else None,
            "viewer": viewer_settings(prov),
        }

    @app.get("/api/jobs/{job_id}")
    def status(job_id: str):
        try:
            return status_payload(job_id)
        except KeyError:
            return _error(404, "no such job (it may have been removed)")

    @app.post("/api/jobs/{job_id}/cancel")
    def cancel(job_id: str):
        try:
            store.folder(job_id)
        except KeyError:
            return _error(404, "no such job")
        if not jobs.cancel(job_id):
            return _error(409, "the job has already finished")
        return status_payload(job_id)

    def done_folder(job_id: str) -> Path:
        folder = store.folder(job_id)
        if store.read(job_id).state != "done":
            raise KeyError(job_id)
        return folder

    @app.get("/api/jobs/{job_id}/files/{path:path}")
    def output_file(job_id: str, path: str):
        try:
            done_folder(job_id)
            file = store.output_file(job_id, path)
        except KeyError:
            return _error(404, "no such file")
        return FileResponse(file, headers={"X-Content-Type-Options": "nosniff"})

    @app.get("/api/jobs/{job_id}/download.zip")
    def download_zip(job_id: str):
        try:
            folder = done_folder(job_id)
        except KeyError:
            return _error(404, "no such finished job")
        return FileResponse(folder / "result.zip", media_type="application/zip", filename=f"capture-{job_id}.zip")

    @app.get("/api/jobs/{job_id}/material.glb")
    def download_glb(job_id: str):
        try:
            done_folder(job_id)
            glb = store.output_file(job_id, "material/material.glb")
        except KeyError:
            return _error(404, "no such file")
        return FileResponse(glb, media_type="model/gltf-binary", filename=f"material-{job_id}.glb")

    @app.get("/api/jobs/{job_id}/maps.bin")
    def maps_bin(job_id: str):
        try:
            done_folder(job_id)
            paths = [store.output_file(job_id, f"material/{name}.exr") for name, _ in MAPS]
        except KeyError:
            return _error(404, "no such file")
        return Response(maps_bytes(paths), media_type="application/octet-stream")

    return UploadLimit(app, limit + _FORM_OVERHEAD, too_large)


def photo_plane(frame: dict) -> dict:
    """Where the photo's pixels sit on the material plane (``materials.frame.Frame``):
    pixel (i, j) of the H x W maps has its centre at ``x = x0 + (j + 0.5) dx``,
    ``y = y0 - (i + 0.5) dy`` (scene units; row 0 is the top, +y). The same arithmetic
    as ``Frame.pixel_to_plane``, which is affine in (i, j)."""
    (ph, pw), (sh_, sw_) = frame["photo_size"], frame["scaled_size"]
    (top, left), (sh, sw) = frame["origin"], frame["size"]
    size = float(frame.get("plane_size", 4.0))
    return {
        "x0": (-left / sw - 0.5) * size,
        "dx": (sw_ / pw) / sw * size,
        "y0": (top / sh + 0.5) * size,
        "dy": (sh_ / ph) / sh * size,
        "width": pw,
        "height": ph,
    }


def viewer_settings(provenance: dict) -> dict:
    """What the viewer needs to render like ``kernels.render`` with the capture's render
    keywords (``CaptureScene.render_kwargs``): intensity, falloff, roughness floor, camera."""
    from kernels.render import resolve_preset

    render = dict(provenance["scene"]["render"])
    preset = resolve_preset(render.pop("preset", "dgrsise"), **render)
    plane = photo_plane(provenance["frame"])
    return {
        "width": plane["width"],
        "height": plane["height"],
        "plane": plane,
        "camera": provenance["scene"]["camera_pos"],
        "intensity": list(preset.intensity),
        "inverse_square": bool(preset.inverse_square),
        "roughness_floor": preset.roughness_floor,
        "maps": [{"name": name, "channels": c} for name, c in MAPS],
    }


def maps_bytes(paths: list[Path]) -> bytes:
    """The maps' EXRs as one float32 little-endian buffer: each map ``[H, W, C]`` row by
    row from the top, in ``MAPS`` order (linear values as stored; normals signed)."""
    from materials.io.exr import read_exr

    arrays = [read_exr(path) for path in paths]
    return b"".join(np.ascontiguousarray(a, dtype="<f4").tobytes() for a in arrays)
