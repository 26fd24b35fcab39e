"""The web app's job store and queue without a browser or a capture: the progress parser
on the CLI's real bar text, paths that must stay inside a job, the queue's bound,
cancellation, failures and a restart, with a stand-in command (a tiny Python process)."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import pytest

from matcap.web.jobs import (
    STAGES,
    CaptureOptions,
    JobQueue,
    JobStore,
    Progress,
    QueueFull,
    capture_command,
    display_name,
    parse_progress,
)

#: Seconds a stand-in job may take (it runs for well under one).
JOB_TIMEOUT_S = 30

# What ``relight capture --relit 2 --refine 5`` wrote to stderr (split at \r and \n):
# the outer bar with its stage postfix, the inner bars with their cursor-up escapes.
CLI_LINES = [
    "capture:   0%|          | 0/8 [00:00<?, ?step/s, 1 check inputs]",
    "capture:  25%|██▌       | 2/8 [00:00<00:00, 267.09step/s, 3 relight]       ",
    "relight:  50%|█████     | 1/2 [00:00<00:00,  3.1image/s]\x1b[A",
    "capture:  62%|██████▎   | 5/8 [00:00<00:00,  9.98step/s, 6 refine]  ",
    "refine (full resolution):  40%|████      | 2/5 [00:00<00:00,  7.31it/s, loss=0.12183]\x1b[A",
]


def test_progress_from_the_cli_bars():
    p = Progress()
    assert p.label().startswith("starting")
    assert parse_progress(CLI_LINES[0], p) and p.percent == 0.0 and p.label() == "step 1/8: check inputs"
    parse_progress(CLI_LINES[1], p)
    assert (p.done, p.stage) == (2, "3 relight")
    parse_progress(CLI_LINES[2], p)
    assert p.percent == pytest.approx(100 * 2.5 / STAGES, abs=0.1)
    assert p.label() == "step 3/8: relight (relight 1/2)"
    parse_progress(CLI_LINES[3], p)  # a new step resets the inner bar
    assert (p.done, p.stage, p.inner) == (5, "6 refine", 0.0)
    parse_progress(CLI_LINES[4], p)
    assert p.percent == pytest.approx(100 * 5.4 / STAGES, abs=0.1)
    for other in ("wrote 64x64 maps (material/, material.glb) to out", "\x1b[A", "Traceback (most recent call last):"):
        assert not parse_progress(other, p)


def test_options_are_checked_and_become_flags():
    opts = CaptureOptions(relit=2, relighter="lambertian", refine=5, fov=60.0).check(["lambertian"])
    argv = capture_command(Path("in.png"), Path("out"), opts)
    assert argv[1:5] == ["-m", "matcap.cli", "capture", "in.png"]
    assert argv[argv.index("--fov") + 1] == "60.0" and argv[argv.index("--relighter") + 1] == "lambertian"
    for bad, word in (
        (dict(relit=8), "relit"),
        (dict(refine=-1), "refinement"),
        (dict(fov=180.0), "field of view"),
        (dict(relighter="--overwrite"), "relighter"),
        (dict(relighter="nope"), "unknown relighter"),
    ):
        with pytest.raises(ValueError, match=word):
            CaptureOptions(**bad).check(["lambertian", "diffusion"])


def test_display_name_is_never_a_path():
    assert display_name("../../etc/passwd") == "passwd"
    assert display_name("C:\\Users\\me\\wood.png") == "wood.png"
    assert display_name("a\nb\x00.png") == "ab.png"
    assert display_name("") == "photo"
    assert len(display_name("x" * 500)) == 80


def make_job(store: JobStore, tmp_path: Path, name: str = "p.png") -> str:
    upload = store.new_temp(".png")
    upload.write_bytes(b"\x89PNG\r\n\x1a\n")
    return store.create(upload, "png", name, CaptureOptions(relit=0, relighter="lambertian", refine=0)).id


def test_store_paths_stay_inside_the_job(tmp_path):
    store = JobStore(tmp_path / "data")
    job_id = make_job(store, tmp_path)
    out = store.folder(job_id) / "out"
    (out / "material").mkdir(parents=True)
    (out / "material" / "diffuse.png").write_bytes(b"x")
    (out / "escape.png").symlink_to(tmp_path / "data" / "jobs" / job_id / "job.json")
    assert store.output_file(job_id, "material/diffuse.png").name == "diffuse.png"
    for bad in ("../job.json", "material/../../job.json", "/etc/passwd", "escape.png", "material", "", "a\0b"):
        with pytest.raises(KeyError):
            store.output_file(job_id, bad)
    for bad_id in ("../jobs", job_id.upper(), job_id + "0", "0" * 16):
        with pytest.raises(KeyError):
            store.folder(bad_id)
    # The upload went in under a fixed name; tmp/ is empty again.
    assert sorted(p.name for p in store.folder(job_id).iterdir()) == ["input.png", "job.json", "out"]
    assert not any(store.tmp.iterdir())


def stand_in(script: str):
    """A ``command`` for ``JobQueue``: runs ``script`` with the out folder as argv[1]."""

    def command(photo: Path, out: Path, options: CaptureOptions) -> list[str]:
        return [sys.executable, "-c", script, str(out)]

    return command


# Writes the marker file of a finished capture after printing two bars.
SUCCEEDS = """
import sys, pathlib, time
out = pathlib.Path(sys.argv[1]); out.mkdir()
for n in range(9):
    sys.stderr.write(f"\\rcapture: {100*n//8:3d}%|#         | {n}/8 [00:00<00:00, 1step/s, {min(n+1,8)} step]")
    sys.stderr.flush()
(out / "provenance.json").write_text("{}")
"""
FAILS = "import sys; print('relight capture: error: photo is too dark', file=sys.stderr); sys.exit(2)"
CRASHES = "raise RuntimeError('kernel exploded')"
SLEEPS = "import time; time.sleep(60)"


def wait_final(store: JobStore, job_id: str) -> dict:
    deadline = time.monotonic() + JOB_TIMEOUT_S
    while time.monotonic() < deadline:
        job = store.read(job_id)
        if job.state in ("done", "failed", "cancelled"):
            return job.to_dict()
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} did not finish: {store.read(job_id)}")


@pytest.mark.parametrize(
    ("script", "state", "error"),
    [
        (SUCCEEDS, "done", None),
        (FAILS, "failed", "photo is too dark"),
        (CRASHES, "failed", "RuntimeError: kernel exploded"),
    ],
)
def test_queue_runs_jobs_and_reports_the_outcome(tmp_path, script, state, error):
    store = JobStore(tmp_path / "data")
    queue = JobQueue(store, command=stand_in(script))
    queue.start()
    try:
        job_id = make_job(store, tmp_path)
        queue.submit(job_id)
        job = wait_final(store, job_id)
    finally:
        queue.stop()
    assert job["state"] == state
    if error is None:
        assert job["percent"] == 100.0 and (store.folder(job_id) / "result.zip").is_file()
    else:
        assert error in job["error"]


# Draws the bar of a long step (tqdm: "\\r" first, the bar, no line end) and stays in it.
LONG_STEP = """
import sys, time
for n, stage in ((3, "4 capture"), (4, "5 estimate")):
    sys.stderr.write(f"\\rcapture: {100*n//8:3d}%|#####     | {n}/8 [00:00<00:00, 1step/s, {stage}]  ")
    sys.stderr.flush()
time.sleep(60)
"""


def test_the_status_shows_the_step_running_now(tmp_path):
    # The bar on screen is not followed by a separator until the next redraw; the status
    # must show it while the step runs, not the bar before it.
    store = JobStore(tmp_path / "data")
    queue = JobQueue(store, command=stand_in(LONG_STEP))
    queue.start()
    try:
        job_id = make_job(store, tmp_path)
        queue.submit(job_id)
        deadline = time.monotonic() + JOB_TIMEOUT_S
        while store.read(job_id).stage != "step 5/8: estimate" and time.monotonic() < deadline:
            time.sleep(0.05)
        job = store.read(job_id)
        assert (job.state, job.stage, job.percent) == ("running", "step 5/8: estimate", 50.0)
        assert queue.cancel(job_id)
        wait_final(store, job_id)
    finally:
        queue.stop()
    # The bar went to the status, not to the log.
    assert "capture:" not in (store.folder(job_id) / "log.txt").read_text()


def test_queue_is_bounded_cancellable_and_survives_a_restart(tmp_path):
    store = JobStore(tmp_path / "data")
    queue = JobQueue(store, max_pending=2, command=stand_in(SLEEPS))
    queue.start()
    try:
        running = make_job(store, tmp_path)
        queue.submit(running)
        deadline = time.monotonic() + JOB_TIMEOUT_S
        while store.read(running).state != "running" and time.monotonic() < deadline:
            time.sleep(0.05)
        waiting = [make_job(store, tmp_path) for _ in range(2)]
        for job_id in waiting:
            queue.submit(job_id)
        assert [queue.position(j) for j in waiting] == [1, 2]
        with pytest.raises(QueueFull):
            queue.submit(make_job(store, tmp_path))
        assert queue.cancel(waiting[0]) and store.read(waiting[0]).state == "cancelled"
        assert queue.cancel(running)
        assert wait_final(store, running)["state"] == "cancelled"
        assert not (store.folder(running) / "out").exists()
    finally:
        queue.stop()
    # A new server over the same folder re-queues the one still waiting and runs it.
    left = waiting[1]
    assert store.read(left).state in ("queued", "running")
    queue = JobQueue(JobStore(tmp_path / "data"), command=stand_in(SUCCEEDS))
    queue.start()
    try:
        assert wait_final(store, left)["state"] == "done"
    finally:
        queue.stop()
    status = json.loads((store.folder(left) / "job.json").read_text())
    assert status["state"] == "done"
