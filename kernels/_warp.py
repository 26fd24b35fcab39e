"""Warp runtime glue: quiet initialisation, a writable kernel cache, dtype/device
mapping between torch and Warp, and the CPU thread split.

Warp runs one OS thread per launch on the CPU. Launches release the GIL, so splitting
the batch across a small thread pool uses every core; each thread writes a disjoint
slice of the outputs, so results are bit-identical to a single launch.
"""

from __future__ import annotations

import os
import sys
import tempfile
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from functools import cache

import torch
import warp as wp

__all__ = [
    "ensure_init",
    "warp_device",
    "warp_scalar",
    "cpu_threads",
    "chunk_bounds",
    "parallel_chunks",
    "preload",
    "wp_array",
]

#: Environment variable that overrides where Warp caches compiled kernels.
CACHE_ENV = "DGRSISE_WARP_CACHE"
#: Environment variable that caps the CPU threads the kernels use (default: all cores).
THREADS_ENV = "DGRSISE_KERNEL_THREADS"


def _writable_cache_dir() -> str:
    """The first writable kernel-cache folder: $DGRSISE_WARP_CACHE, ~/.cache, or /tmp."""
    candidates = [
        os.environ.get(CACHE_ENV),
        os.path.join(os.path.expanduser("~"), ".cache", "dgrsise", "warp"),
        os.path.join(tempfile.gettempdir(), "dgrsise-warp-cache"),
    ]
    for path in candidates:
        if not path:
            continue
        try:
            os.makedirs(path, exist_ok=True)
            if os.access(path, os.W_OK):
                return path
        except OSError:
            continue
    raise RuntimeError(f"no writable Warp kernel cache folder; set {CACHE_ENV}")


@contextmanager
def _native_stderr_silenced(active: bool) -> Iterator[None]:
    """Send file descriptor 2 to /dev/null while active (native printf output only)."""
    if not active:
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


@cache
def ensure_init() -> None:
    """Initialise Warp once: errors only in the log (no banner), cache in a writable place.

    Without a CUDA device, Warp's native library prints a "could not load the CUDA
    driver" line on stderr at init; on a CPU-only machine that line is noise in user
    output, so init runs with native stderr silenced there (Python errors still raise).
    """
    wp.config.log_level = wp.LOG_ERROR
    wp.config.kernel_cache_dir = _writable_cache_dir()
    with _native_stderr_silenced(not torch.cuda.is_available()):
        wp.init()


def warp_device(device: torch.device) -> str:
    """Warp device string for a torch device ('cpu' or 'cuda:N')."""
    if device.type == "cpu":
        return "cpu"
    if device.type == "cuda":
        return f"cuda:{device.index if device.index is not None else torch.cuda.current_device()}"
    raise ValueError(f"kernels run on cpu or cuda tensors, got device {device}")


def warp_scalar(dtype: torch.dtype):
    """Warp scalar type for float32 / float64 torch tensors."""
    if dtype == torch.float32:
        return wp.float32
    if dtype == torch.float64:
        return wp.float64
    raise TypeError(f"kernels take float32 or float64 tensors, got {dtype}")


def wp_array(t: torch.Tensor, dtype=None):
    """Zero-copy Warp view of a torch tensor (no grad tracking: autograd stays in torch)."""
    return wp.from_torch(t, dtype=dtype, requires_grad=False)


@cache
def _pool(threads: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(max_workers=threads, thread_name_prefix="dgrsise-kernels")


def cpu_threads() -> int:
    """Threads for CPU launches: $DGRSISE_KERNEL_THREADS, else the usable cores."""
    env = os.environ.get(THREADS_ENV)
    if env:
        return max(1, int(env))
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def chunk_bounds(n: int, device: torch.device) -> list[tuple[int, int]]:
    """Split ``range(n)`` into (start, count) chunks: one on CUDA, one per CPU thread."""
    threads = min(cpu_threads(), n) if device.type == "cpu" else 1
    bounds = [round(i * n / max(threads, 1)) for i in range(max(threads, 1) + 1)]
    return [(bounds[i], bounds[i + 1] - bounds[i]) for i in range(len(bounds) - 1) if bounds[i + 1] > bounds[i]]


def preload(kernel, device: str) -> None:
    """Load ``kernel``'s module on ``device`` (compiling it on a cold cache) before launches
    fan out to the thread pool. Warp loads a module on its first launch without a
    per-module lock, so concurrent first launches from the pool threads would each compile
    it (measured on 2 cores: 14.5 s cold instead of 2.2 s)."""
    _preload(kernel.module, device)


@cache
def _preload(module, device: str) -> None:
    wp.load_module(module, device=device)


def parallel_chunks(chunks: list[tuple[int, int]], launch: Callable[[int, int, int], None]) -> None:
    """Run ``launch(chunk_index, start, count)`` for every chunk, on the thread pool when
    there are several. Each chunk must write disjoint outputs, so the result does not
    depend on the split."""
    if len(chunks) == 1:
        launch(0, *chunks[0])
        return
    futures = [_pool(len(chunks)).submit(launch, i, s, c) for i, (s, c) in enumerate(chunks)]
    for f in futures:
        f.result()
