"""Capture jobs of the web app: a folder per job on disk, a bounded queue, worker threads
that run ``relight capture`` in a subprocess.

Why a subprocess per job (not the Python API in the server): a capture holds torch and
Warp memory (up to about 1.7 GB at 2048 px, ``matcap.capture.refine_memory_bytes``) that
the operating system gets back when the process ends; a crash in a kernel or an
out-of-memory kill ends the job, not the server; a job is cancelled by killing its
process group; and the CLI is the checked path users run (``--out`` written atomically,
one error line on a bad input). The cost is the start-up (imports, model loading: a few
seconds), small next to a capture. Progress comes from the CLI's own tqdm bars on
stderr (``parse_progress``), so nothing is added to the pipeline for the app.

A job's folder, ``<data>/jobs/<id>/`` (``id``: 16 random hex digits, ``JOB_ID``)::

    job.json     the status (``Job``), rewritten atomically at every change; a page
                 reload or a server restart reads it back
    input.png    the uploaded photo (.png, .jpg or .exr after its first bytes; the
                 uploaded file name is kept for display only, never as a path)
    log.txt      the CLI's output lines (progress bars left out)
    out/         the ``relight capture`` folder (``CaptureOutput.save``), atomic
    result.zip   out/ zipped, made when the job succeeds

A folder appears under ``jobs/`` complete (input and job.json) or not at all: it is
filled under ``<data>/tmp/`` and renamed.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import shutil
import signal
import subprocess
import sys
import threading
import time
import zipfile
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from pathlib import Path

__all__ = [
    "Job",
    "JobStore",
    "JobQueue",
    "CaptureOptions",
    "QueueFull",
    "Progress",
    "parse_progress",
    "capture_command",
    "JOB_ID",
    "STATES",
    "STAGES",
    "DEFAULT_MAX_UPLOAD_MB",
]

#: A job id: 16 lowercase hex digits (64 random bits: not guessable by another user).
JOB_ID = re.compile(r"^[0-9a-f]{16}$")
#: Job states; the last three are final.
STATES = ("queued", "running", "done", "failed", "cancelled")
FINAL_STATES = ("done", "failed", "cancelled")
#: Steps of ``CapturePipeline.__call__`` (the CLI's outer bar counts them).
STAGES = 8
#: A relighter name: a registry name, never an option (a leading "-" would read as a flag).
_RELIGHTER_NAME = re.compile(r"^[a-z][a-z0-9_]{0,39}$")
#: Photo suffix by format (``materials.io.photo.PHOTO_FORMATS``).
SUFFIXES = {"png": ".png", "jpeg": ".jpg", "exr": ".exr"}
#: Longest displayed upload name (characters); longer ones are shortened.
_MAX_NAME = 80
#: Seconds between status writes while a bar moves (a stage change is written at once).
_WRITE_INTERVAL_S = 0.25
#: Seconds a cancelled process gets after SIGTERM before SIGKILL.
_KILL_GRACE_S = 5.0
#: Default upload limit, megabytes: a 2048 x 2048 16-bit PNG is at most 25 MB, an EXR
#: of that size about 50 MB uncompressed (float32 RGB); phone JPEGs are 2-10 MB.
DEFAULT_MAX_UPLOAD_MB = 64
#: Lines of the CLI's output kept for a failure message.
_TAIL_LINES = 20


class QueueFull(RuntimeError):
    """The queue holds its maximum of pending jobs."""


# ---------------------------------------------------------------------- options
@dataclass(frozen=True)
class CaptureOptions:
    """The page's settings of one capture, checked; ``cli_args`` turns them into flags.

    Attributes:
        relit: relit views K, 0..7 (``--relit``).
        relighter: registry name (``--relighter``).
        refine: refinement steps at full resolution (``--refine``).
        fov: field of view across the photo's long side, degrees, or None (EXIF or 45).
        max_side: photos longer than this are downscaled (``--max-side``).
    """

    relit: int = 7
    relighter: str = "diffusion"
    refine: int = 100
    fov: float | None = None
    max_side: int = 2048

    #: Bounds (checked here, so a bad value is a message on the page, not a failed job).
    MAX_RELIT = 7
    MAX_REFINE = 2000

    def check(self, relighters: Iterable[str] | None = None) -> CaptureOptions:
        """Return self, or raise ``ValueError`` naming the bad setting."""
        if not 0 <= self.relit <= self.MAX_RELIT:
            raise ValueError(f"relit views must be 0..{self.MAX_RELIT}, got {self.relit}")
        if not 0 <= self.refine <= self.MAX_REFINE:
            raise ValueError(f"refinement steps must be 0..{self.MAX_REFINE}, got {self.refine}")
        if self.fov is not None and not 0 < self.fov < 180:
            raise ValueError(f"field of view must lie strictly between 0 and 180 degrees, got {self.fov}")
        if not _RELIGHTER_NAME.match(self.relighter):
            raise ValueError(f"relighter must be a registry name, got {self.relighter!r}")
        known = list(relighters) if relighters is not None else None
        if known is not None and self.relighter not in known:
            raise ValueError(f"unknown relighter {self.relighter!r}; known: {', '.join(known)}")
        return self

    def cli_args(self) -> list[str]:
        args = ["--relit", str(self.relit), "--relighter", self.relighter, "--refine", str(self.refine)]
        if self.fov is not None:
            args += ["--fov", repr(float(self.fov))]
        return args + ["--max-side", str(self.max_side)]

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> CaptureOptions:
        names = set(CaptureOptions.__dataclass_fields__)
        return CaptureOptions(**{k: v for k, v in d.items() if k in names})


def capture_command(photo: Path, out: Path, options: CaptureOptions) -> list[str]:
    """The ``relight capture`` command line of a job (this interpreter, no shell)."""
    return [sys.executable, "-m", "matcap.cli", "capture", str(photo), "--out", str(out), *options.cli_args()]


# ---------------------------------------------------------------------- progress
@dataclass
class Progress:
    """What the CLI's bars said last. ``done`` steps of ``STAGES`` finished, ``stage``
    the one running (``"3 relight"``), ``inner`` the fraction of its inner bar."""

    done: int = 0
    stage: str = ""
    inner: float = 0.0
    inner_text: str = ""

    @property
    def percent(self) -> float:
        return round(100.0 * min(STAGES, self.done + min(self.inner, 1.0)) / STAGES, 1)

    def label(self) -> str:
        if not self.stage:
            return "starting (loading the models)"
        number, _, name = self.stage.partition(" ")
        text = f"step {number}/{STAGES}: {name}" if number.isdigit() else self.stage
        return f"{text} ({self.inner_text})" if self.inner_text else text


# "desc:  37%|####      | 3/8 [00:01<00:02,  2.10step/s, 4 capture]": tqdm's default
# layout; the bar itself may be unicode blocks or '#'.
_BAR = re.compile(r"^\s*(?P<desc>[^:|\r\n]+?):\s+\d+%\|[^|]*\|\s*(?P<n>\d+)/(?P<total>\d+)(?:\s*\[(?P<info>[^\]]*)\])?")
# Terminal escapes tqdm adds around nested bars (cursor up: "\x1b[A").
_ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
# The outer bar's postfix: "<number> <name>" (``matcap.capture._Stages``).
_STAGE = re.compile(r"(?:^|,\s*)(\d+ [a-z][a-z ()-]*)$")


def parse_progress(segment: str, progress: Progress) -> bool:
    """Update ``progress`` from one ``\\r``/``\\n``-separated piece of the CLI's stderr;
    return whether it was a progress bar (such pieces are left out of the log)."""
    m = _BAR.match(_ANSI.sub("", segment))
    if not m:
        return False
    desc, n, total = m["desc"].strip(), int(m["n"]), max(1, int(m["total"]))
    if desc == "capture":
        stage = _STAGE.search((m["info"] or "").strip())
        if n != progress.done or (stage and stage[1] != progress.stage):
            progress.inner, progress.inner_text = 0.0, ""
        progress.done = n
        if stage:
            progress.stage = stage[1]
    else:
        progress.inner = n / total
        progress.inner_text = f"{desc} {n}/{total}"
    return True


# ---------------------------------------------------------------------- the store
@dataclass
class Job:
    """One job's status (``job.json``)."""

    id: str
    state: str
    created: float
    options: dict
    photo_name: str
    photo_format: str
    input: str
    stage: str = "queued"
    percent: float = 0.0
    started: float | None = None
    finished: float | None = None
    error: str | None = None
    returncode: int | None = None

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> Job:
        names = set(Job.__dataclass_fields__)
        return Job(**{k: v for k, v in d.items() if k in names})


def display_name(name: str | None) -> str:
    """The uploaded file's name, for display only: its last path part, printable
    characters, at most ``_MAX_NAME`` of them."""
    base = re.split(r"[\\/]", name or "")[-1]
    clean = "".join(ch for ch in base if ch.isprintable()).strip() or "photo"
    return clean if len(clean) <= _MAX_NAME else clean[: _MAX_NAME - 3] + "..."


class JobStore:
    """Job folders under ``<root>/jobs``; every path comes from a checked id."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root).resolve()
        self.jobs = self.root / "jobs"
        self.tmp = self.root / "tmp"
        self.jobs.mkdir(parents=True, exist_ok=True)
        self.tmp.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        # What a killed server left half-made in tmp/ is garbage (nothing there is a job).
        for stale in self.tmp.iterdir():
            shutil.rmtree(stale, ignore_errors=True) if stale.is_dir() else stale.unlink(missing_ok=True)

    # ------------------------------------------------------------------ paths
    def folder(self, job_id: str) -> Path:
        """The job's folder; ``KeyError`` for an id that is malformed or unknown."""
        if not isinstance(job_id, str) or not JOB_ID.match(job_id):
            raise KeyError(job_id)
        path = self.jobs / job_id
        if not (path / "job.json").is_file():
            raise KeyError(job_id)
        return path

    def output_file(self, job_id: str, relative: str) -> Path:
        """A regular file inside the job's ``out/`` folder, or ``KeyError``: the path is
        resolved (links followed) and must stay inside ``out/``."""
        out = (self.folder(job_id) / "out").resolve()
        if not relative or "\0" in relative or relative.startswith(("/", "\\")):
            raise KeyError(relative)
        path = (out / relative).resolve()
        if not path.is_relative_to(out) or not path.is_file():
            raise KeyError(relative)
        return path

    def new_temp(self, suffix: str = "") -> Path:
        return self.tmp / f"{secrets.token_hex(8)}{suffix}"

    # ------------------------------------------------------------------ records
    def create(self, upload: Path, fmt: str, photo_name: str, options: CaptureOptions) -> Job:
        """Make a job from a checked upload (moved, not copied); atomic: the folder is
        filled under tmp/ and renamed into jobs/."""
        job_id = secrets.token_hex(8)
        while (self.jobs / job_id).exists():  # 64 random bits: practically never taken
            job_id = secrets.token_hex(8)
        staging = self.tmp / f"job-{job_id}"
        staging.mkdir()
        try:
            name = "input" + SUFFIXES[fmt]
            os.replace(upload, staging / name)
            job = Job(
                id=job_id,
                state="queued",
                created=time.time(),
                options=options.to_dict(),
                photo_name=display_name(photo_name),
                photo_format=fmt,
                input=name,
            )
            _write_json(staging / "job.json", job.to_dict())
            os.replace(staging, self.jobs / job_id)
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise
        return job

    def read(self, job_id: str) -> Job:
        return Job.from_dict(json.loads((self.folder(job_id) / "job.json").read_text(encoding="utf-8")))

    def update(self, job_id: str, **changes) -> Job:
        with self._lock:
            job = self.read(job_id)
            for key, value in changes.items():
                setattr(job, key, value)
            _write_json(self.folder(job_id) / "job.json", job.to_dict())
            return job

    def ids(self) -> list[str]:
        """Ids of the jobs on disk, oldest first."""
        found = []
        for path in self.jobs.iterdir():
            if JOB_ID.match(path.name) and (path / "job.json").is_file():
                found.append((path.stat().st_mtime, path.name))
        return [name for _, name in sorted(found)]


def _write_json(path: Path, data: dict) -> None:
    """Write JSON atomically (a reader never sees half a file)."""
    tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def zip_folder(folder: Path, target: Path, top: str) -> None:
    """Zip ``folder`` into ``target`` (entries under ``top/``), atomically."""
    tmp = target.with_name(f".{target.name}.{secrets.token_hex(4)}.tmp")
    try:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            for path in sorted(folder.rglob("*")):
                if path.is_file() and not path.is_symlink():
                    zf.write(path, f"{top}/{path.relative_to(folder).as_posix()}")
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


# ---------------------------------------------------------------------- the queue
class JobQueue:
    """A bounded FIFO of job ids and ``workers`` threads that run them one each.

    Args:
        store: the ``JobStore``.
        workers: jobs run at the same time (each is a process with its own memory).
        max_pending: jobs waiting at most; ``submit`` raises ``QueueFull`` beyond.
        command: ``(photo, out, options) -> argv`` (``capture_command``; tests may swap it).
        env: environment of the job processes (default: the server's).
    """

    def __init__(
        self,
        store: JobStore,
        *,
        workers: int = 1,
        max_pending: int = 16,
        command: Callable[[Path, Path, CaptureOptions], list[str]] = capture_command,
        env: dict | None = None,
    ):
        if workers < 1 or max_pending < 1:
            raise ValueError(f"workers and max_pending must be >= 1, got {workers}, {max_pending}")
        self.store = store
        self.workers = workers
        self.max_pending = max_pending
        self.command = command
        self.env = env
        self._pending: list[str] = []
        self._running: dict[str, subprocess.Popen | None] = {}
        self._cancelled: set[str] = set()
        self._cond = threading.Condition()
        self._threads: list[threading.Thread] = []
        self._stopping = False

    # ------------------------------------------------------------------ control
    def start(self) -> None:
        """Re-queue what a previous server left queued or running, then start the workers."""
        for job_id in self.store.ids():
            job = self.store.read(job_id)
            if job.state in ("queued", "running"):
                folder = self.store.folder(job_id)
                if (folder / "out" / "provenance.json").is_file():
                    self._finish_success(job_id, folder)  # finished; only its status was not written
                    continue
                self.store.update(job_id, state="queued", stage="queued", percent=0.0)
                self._pending.append(job_id)
        for k in range(self.workers):
            thread = threading.Thread(target=self._work, name=f"capture-worker-{k}", daemon=True)
            thread.start()
            self._threads.append(thread)

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the workers; running captures are killed (their jobs stay ``running`` on
        disk and are re-queued by the next ``start``)."""
        with self._cond:
            self._stopping = True
            procs = [p for p in self._running.values() if p is not None]
            self._cond.notify_all()
        for proc in procs:
            _kill(proc)
        for thread in self._threads:
            thread.join(timeout)

    def submit(self, job_id: str) -> None:
        with self._cond:
            if len(self._pending) >= self.max_pending:
                raise QueueFull(f"the queue is full ({self.max_pending} photos waiting); try again in a few minutes")
            self._pending.append(job_id)
            self._cond.notify()

    def position(self, job_id: str) -> int | None:
        """1-based place in the queue, or None when not waiting."""
        with self._cond:
            return self._pending.index(job_id) + 1 if job_id in self._pending else None

    def cancel(self, job_id: str) -> bool:
        """Cancel a waiting or running job; False when it already finished."""
        with self._cond:
            if job_id in self._pending:
                self._pending.remove(job_id)
                self.store.update(job_id, state="cancelled", stage="cancelled", finished=time.time())
                return True
            if job_id in self._running:
                self._cancelled.add(job_id)
                proc = self._running[job_id]
            else:
                return False
        if proc is not None:
            _kill(proc)
        return True

    # ------------------------------------------------------------------ workers
    def _work(self) -> None:
        while True:
            with self._cond:
                while not self._pending and not self._stopping:
                    self._cond.wait()
                if self._stopping:
                    return
                job_id = self._pending.pop(0)
                self._running[job_id] = None
            try:
                self._run(job_id)
            except Exception as exc:  # a bug here must fail the job, not kill the worker
                self.store.update(job_id, state="failed", stage="failed", error=f"internal error: {exc}")
            finally:
                with self._cond:
                    self._running.pop(job_id, None)
                    self._cancelled.discard(job_id)

    def _run(self, job_id: str) -> None:
        folder = self.store.folder(job_id)
        job = self.store.read(job_id)
        out = folder / "out"
        argv = self.command(folder / job.input, out, CaptureOptions.from_dict(job.options))
        self.store.update(job_id, state="running", stage=Progress().label(), percent=0.0, started=time.time())
        progress, tail = Progress(), []
        with open(folder / "log.txt", "w", encoding="utf-8") as log:
            log.write("$ relight " + " ".join(argv[3:]) + "\n")
            proc = subprocess.Popen(
                argv,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                cwd=folder,
                env=self.env,
                start_new_session=True,  # its own process group: a cancel kills its children too
            )
            with self._cond:
                self._running[job_id] = proc
                cancelled = job_id in self._cancelled or self._stopping
            if cancelled:
                _kill(proc)
            last_write, last_label = 0.0, ""
            for segment, complete in _segments(proc.stdout):
                if not complete and not _ANSI.sub("", segment).rstrip().endswith("]"):
                    continue  # part of a line or of a bar: wait for the rest
                if parse_progress(segment, progress):
                    label, now = progress.label(), time.monotonic()
                    if label != last_label or now - last_write > _WRITE_INTERVAL_S:
                        self.store.update(job_id, stage=label, percent=progress.percent)
                        last_write, last_label = now, label
                elif complete and (text := _ANSI.sub("", segment).strip()):
                    log.write(text + "\n")
                    log.flush()
                    tail = (tail + [text])[-_TAIL_LINES:]
            rc = proc.wait()
        with self._cond:
            cancelled = job_id in self._cancelled
            stopping = self._stopping
        if stopping and not cancelled:
            return  # left "running": the next start re-queues it
        if cancelled:
            shutil.rmtree(out, ignore_errors=True)
            self.store.update(job_id, state="cancelled", stage="cancelled", finished=time.time(), returncode=rc)
        elif rc == 0 and (out / "provenance.json").is_file():
            self._finish_success(job_id, folder, rc)
        else:
            self.store.update(
                job_id,
                state="failed",
                stage="failed",
                finished=time.time(),
                returncode=rc,
                error=_failure_message(rc, tail),
            )

    def _finish_success(self, job_id: str, folder: Path, rc: int | None = 0) -> None:
        self.store.update(job_id, stage="packing the download", percent=100.0)
        zip_folder(folder / "out", folder / "result.zip", top=f"capture-{job_id}")
        self.store.update(job_id, state="done", stage="done", percent=100.0, finished=time.time(), returncode=rc)


def _segments(stream) -> Iterable[tuple[str, bool]]:
    """Pieces of a byte stream split at ``\\r`` and ``\\n`` (tqdm redraws with ``\\r``), as
    ``(text, complete)``. tqdm writes ``\\r`` *before* each bar, so the bar on screen is the
    piece after the last separator, complete only once the next redraw starts: it is also
    yielded as it stands after every read (``complete=False``), else the page would show
    the previous bar for as long as a step runs."""
    buf = b""
    while True:
        chunk = stream.read1(65536) if hasattr(stream, "read1") else stream.read(65536)
        if not chunk:
            break
        buf += chunk
        *pieces, buf = re.split(rb"[\r\n]", buf)
        for piece in pieces:
            yield piece.decode("utf-8", errors="replace"), True
        if buf:
            yield buf.decode("utf-8", errors="replace"), False
    if buf:
        yield buf.decode("utf-8", errors="replace"), True


def _failure_message(rc: int, tail: list[str]) -> str:
    """One sentence for the page: the CLI's error line, a crash's last line, or the signal."""
    prefix = "relight capture: error: "
    for line in reversed(tail):
        if line.startswith(prefix):
            return line[len(prefix) :]
    if rc < 0:
        name = signal.Signals(-rc).name if -rc in signal.Signals._value2member_map_ else str(-rc)
        hint = " (out of memory?)" if -rc == signal.SIGKILL else ""
        return f"the capture process was killed by {name}{hint}"
    last = tail[-1] if tail else "no output"
    return f"the capture failed (exit code {rc}): {last}"


def _kill(proc: subprocess.Popen) -> None:
    """SIGTERM the job's process group, SIGKILL it if it is still there after a grace."""
    try:
        os.killpg(proc.pid, signal.SIGTERM)
    except ProcessLookupError:
        return
    try:
        proc.wait(_KILL_GRACE_S)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
