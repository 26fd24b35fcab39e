"""Benchmark the Warp kernels against their pure-torch twins (``kernels.reference``).

Usage::

    python benchmarks/bench_kernels.py [--quick] [--threads 1,2] [--cases a,b] [--out benchmarks/results/kernels.json]

Three implementations per case: Warp (``kernels``), the eager pure-torch twin
(``kernels.reference``, "torch") and, for the rendering cases, ``torch.compile`` of that
same twin ("compile": Inductor's C++ with the CPU's vector units, the peer a user would
pick instead of Warp). All get the same thread budget: ``torch.set_num_threads(N)`` and
``DGRSISE_KERNEL_THREADS=N``, one table row group per N of ``--threads`` (default 1,2).
Each case runs in subprocesses:

- timings: one subprocess per case and thread count builds every side and interleaves
  their repeats (Warp, torch, compile, Warp, ...) after warm-up, so a change in the
  shared machine's load hits all alike; median and min/max (and quartiles in the JSON)
  over the repeats. Forward and backward are timed separately. Throughput and ratios
  use wall-clock medians; the process CPU time of a step (all threads) is reported
  beside them, since on a shared machine the wall clock also measures the other jobs.
  torch.compile's compile time (its first call minus a steady call, forward and
  backward graphs together) is reported apart and never enters the run time;
- peak extra memory: a fresh subprocess per side measures the rise of the process's
  peak RSS (``VmHWM``, reset through ``/proc/self/clear_refs``; ``ru_maxrss`` as a
  fallback) during one step over its RSS once the inputs are allocated and the kernels
  loaded. It counts the outputs, the saved tensors, the gradients and every temporary
  (tracemalloc does not see torch's allocations).

Compile time is measured apart from run time, per Warp module: a subprocess with an
empty kernel cache (``DGRSISE_WARP_CACHE`` = a fresh folder) times each module's first
call minus a steady call (cold compile); a second subprocess on the same cache does the
same (warm load from the cache).

The CPU's limit (``peak_worker``, one thread): a STREAM-like copy and triad over arrays
far larger than the caches (memory bandwidth) and a chain of fused multiply-adds on an
L1-resident array compiled by torch.compile (vector FMA throughput). The forward
render's limit is min(FMA rate / FLOPs per pixel-light, bandwidth / bytes per
pixel-light), with both per-pixel-light costs counted from the kernel's code
(``RENDER_FWD_FLOPS``, ``render_fwd_bytes``); each implementation's forward throughput
is reported as a fraction of it.

Results go to a JSON file and are printed as markdown tables (also written next to the
JSON, same name with ``.md``); the JSON records the CPU model, the thread counts and the
load average before and after each case.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from functools import cache
from pathlib import Path
from types import SimpleNamespace

DEFAULT_OUT = Path(__file__).resolve().parent / "results" / "kernels.json"
THREADS_ENV = "DGRSISE_KERNEL_THREADS"
CACHE_ENV = "DGRSISE_WARP_CACHE"
IMPLS = ("warp", "torch", "compile")
#: FLOPs of one pixel-light of the forward render, counted from ``kernels.brdf`` (every
#: add, multiply, compare-select, division and square root as one; the Fresnel 2^x as
#: one): light and view directions 2 x (3 sub + dot 5 + eps 1 + sqrt 1 + 3 div) = 26; half
#: vector 3 + 5 + 1 + 1 + 3 = 13; four clamped dots 4 x 6 = 24; roughness, alpha, k, a2 4;
#: |n x h|^2 with its select 15; GGX D 3 + 3 = 6; Fresnel exponent 3 + 2^x 1 + blend 9 = 13;
#: the two Smith factors and their product 10; diffuse term 9; shading sum and cosine 10;
#: intensity and inverse square 6. The per-pixel normalisation of n (~10) is spread over
#: the K lights and left out.
RENDER_FWD_FLOPS = 136
#: Cores of the thread counts benchmarked by default: the machine's 2.
DEFAULT_THREADS = "1,2"


def render_fwd_bytes(k: int) -> float:
    """DRAM bytes per pixel-light of the forward render with K lights: the 10 float32 map
    values of a pixel read once for its K lights, 3 float32 radiance values written, and
    the write-allocate read of the output's cache lines (no non-temporal stores)."""
    return 10 * 4 / k + 3 * 4 + 3 * 4


@dataclass(frozen=True)
class Case:
    """One benchmark: an operation, a mode and a problem size."""

    name: str
    op: str  # "render" | "translate" | "rendering_loss"
    mode: str  # "fwd" | "fwd_bwd"
    b: int
    h: int
    w: int
    k: int = 1  # lights (render, rendering_loss)
    c: int = 1  # channels (translate)

    @property
    def work(self) -> int:
        """Work items: pixel-lights for rendering, feature elements for translate."""
        return self.b * self.h * self.w * (self.c if self.op == "translate" else self.k)

    @property
    def unit(self) -> str:
        return "Melem/s" if self.op == "translate" else "Mpixel-lights/s"

    @property
    def impls(self) -> tuple[str, ...]:
        """Implementations benchmarked: torch.compile only for the rendering twins."""
        return IMPLS if self.op in ("render", "rendering_loss") else IMPLS[:2]

    @property
    def size(self) -> str:
        extra = f"C={self.c}" if self.op == "translate" else f"K={self.k}"
        return f"B={self.b} {extra} {self.h}x{self.w}"


def make_cases(quick: bool, names: list[str] | None = None) -> list[Case]:
    if quick:
        cases = [
            Case("render_fwd", "render", "fwd", b=2, k=2, h=64, w=64),
            Case("render_fwd_bwd", "render", "fwd_bwd", b=2, k=2, h=64, w=64),
            Case("translate_fwd", "translate", "fwd", b=2, c=8, h=32, w=32),
            Case("translate_fwd_bwd", "translate", "fwd_bwd", b=2, c=8, h=32, w=32),
            Case("rendering_loss_fwd_bwd", "rendering_loss", "fwd_bwd", b=2, k=3, h=64, w=64),
        ]
        sweep = [32, 64]
    else:
        cases = [
            Case("render_fwd", "render", "fwd", b=8, k=8, h=256, w=256),
            Case("render_fwd_bwd", "render", "fwd_bwd", b=8, k=8, h=256, w=256),
            Case("translate_fwd", "translate", "fwd", b=8, c=64, h=64, w=64),
            Case("translate_fwd_bwd", "translate", "fwd_bwd", b=8, c=64, h=64, w=64),
            Case("rendering_loss_fwd_bwd", "rendering_loss", "fwd_bwd", b=8, k=9, h=256, w=256),
        ]
        sweep = [64, 128, 256, 512]
    b, k = cases[0].b, cases[0].k
    cases += [Case(f"render_fwd_sweep_{s}", "render", "fwd", b=b, k=k, h=s, w=s) for s in sweep]
    if names:
        unknown = set(names) - {c.name for c in cases}
        if unknown:
            raise SystemExit(f"unknown case(s) {sorted(unknown)}; known: {[c.name for c in cases]}")
        cases = [c for c in cases if c.name in names]
    return cases


# ----------------------------------------------------------------------------- worker side
def _rss_kb(field: str) -> int | None:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def _reset_peak() -> bool:
    """Reset VmHWM to the current RSS (Linux >= 4.0); False where that is not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _peak_kb() -> int:
    hwm = _rss_kb("VmHWM")
    return hwm if hwm is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


@cache
def _compiled() -> SimpleNamespace:
    """torch.compile of the rendering twins (static shapes: every case has one shape)."""
    import torch

    from kernels import reference

    return SimpleNamespace(
        render=torch.compile(reference.render, dynamic=False),
        rendering_loss=torch.compile(reference.rendering_loss, dynamic=False),
    )


def _setup(case: Case, impl: str, device: str, seed: int = 0):
    """Inputs and a step function (fwd, or fwd then bwd) for one case and implementation."""
    import torch

    import kernels
    from kernels import reference

    g = torch.Generator().manual_seed(seed)
    need_grad = case.mode == "fwd_bwd"

    def rand(*shape, lo=0.0, hi=1.0):
        return (lo + (hi - lo) * torch.rand(shape, generator=g)).to(device)

    lib = {"warp": kernels, "torch": reference, "compile": _compiled()}[impl]
    if case.op == "translate":
        feats = torch.randn((case.b, case.c, case.h, case.w), generator=g).to(device).requires_grad_(need_grad)
        offs = rand(case.b, 2, lo=-5.0, hi=5.0).requires_grad_(need_grad)
        leaves = [feats, offs]

        def forward():
            return lib.translate(feats, offs)

        cot = torch.randn((case.b, case.c, case.h, case.w), generator=g).to(device) if need_grad else None
    else:
        normal = torch.cat(
            [rand(case.b, 2, case.h, case.w, lo=-0.6, hi=0.6), torch.ones(case.b, 1, case.h, case.w, device=device)], 1
        )
        maps = [
            rand(case.b, 3, case.h, case.w),
            normal / normal.norm(dim=1, keepdim=True),
            rand(case.b, 1, case.h, case.w, lo=0.15, hi=1.0),
            rand(case.b, 3, case.h, case.w),
        ]
        maps = [m.requires_grad_(need_grad) for m in maps]
        light_pos = torch.cat([rand(case.b, case.k, 2, lo=-4, hi=4), rand(case.b, case.k, 1, lo=4, hi=8)], -1)
        camera_pos = torch.tensor([0.0, 0.0, 4.0], device=device)
        leaves = maps
        if case.op == "render":

            def forward():
                return lib.render(*maps, light_pos, camera_pos)

            cot = torch.randn((case.b, case.k, 3, case.h, case.w), generator=g).to(device) if need_grad else None
        else:
            with torch.no_grad():
                target = kernels.render(*[m.detach() * 0.9 for m in maps], light_pos, camera_pos)

            def forward():
                return lib.rendering_loss(*maps, target, light_pos, camera_pos)

            cot = None

    def backward(out):
        for t in leaves:
            t.grad = None
        out.backward(cot)

    return forward, (backward if need_grad else None)


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        import torch

        torch.cuda.synchronize()


def _load(case: Case, impl: str, device: str) -> None:
    """Load (or compile) the Warp modules on a tiny problem, so that neither memory nor
    the timings include it: compile time is reported apart. torch.compile specialises
    on shapes, so its warm-up runs on the case itself (``timing_worker``, ``memory_worker``)."""
    if impl == "compile":
        return
    small = Case(case.name, case.op, case.mode, b=1, h=4, w=4, k=case.k, c=case.c)
    fwd, bwd = _setup(small, impl, device)
    out = fwd()
    if bwd:
        bwd(out)


def memory_worker(case: Case, impl: str, device: str) -> dict:
    """Runs inside a fresh subprocess: the peak RSS rise of one step (fwd, or fwd + bwd)
    over the RSS with the inputs allocated and the kernels loaded."""
    import torch

    torch.set_num_threads(int(os.environ[THREADS_ENV]))
    _load(case, impl, device)
    forward, backward = _setup(case, impl, device)
    if impl == "compile":  # compile on the case's shapes first, outside the measurement
        with torch.enable_grad() if backward else torch.no_grad():
            out = forward()
            if backward:
                backward(out)
            del out
    with torch.enable_grad() if backward else torch.no_grad():
        _sync(device)
        if device.startswith("cuda"):
            # Device memory: every output, saved tensor and gradient of the Warp side is a
            # torch allocation too (kernels/_autograd.py), so torch's allocator sees all.
            torch.cuda.reset_peak_memory_stats(device)
            base = torch.cuda.memory_allocated(device)
            out = forward()
            if backward:
                backward(out)
            _sync(device)
            return {
                "peak_extra_mb": (torch.cuda.max_memory_allocated(device) - base) / 2**20,
                "peak_method": "torch.cuda.max_memory_allocated (device memory)",
            }
        base_kb = _rss_kb("VmRSS") or resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        reset = _reset_peak()
        out = forward()
        if backward:
            backward(out)
        _sync(device)
        peak_kb = _peak_kb()
    return {
        "peak_extra_mb": (peak_kb - base_kb) / 1024,
        "peak_method": "VmHWM reset" if reset else "ru_maxrss (includes earlier peaks)",
    }


def timing_worker(case: Case, device: str, warmup: int, repeats: int) -> dict:
    """Runs inside a subprocess: every implementation of the case, their repeats
    interleaved (warp, torch, compile, warp, ...) so that a change in the machine's load
    hits all alike. The first step of each side is timed apart (``first_s``): for
    torch.compile it includes compiling the forward and backward graphs."""
    import torch

    torch.set_num_threads(int(os.environ[THREADS_ENV]))
    steps, times = {}, {}
    for impl in case.impls:
        _load(case, impl, device)
        steps[impl] = _setup(case, impl, device)
        times[impl] = {"fwd_s": [], "bwd_s": [], "total_s": [], "cpu_s": [], "first_s": None}
    for i in range(1 + warmup + repeats):
        for impl in case.impls:
            forward, backward = steps[impl]
            with torch.enable_grad() if backward else torch.no_grad():
                _sync(device)
                c0, t0 = time.process_time(), time.perf_counter()
                out = forward()
                _sync(device)
                t1 = time.perf_counter()
                if backward:
                    backward(out)
                    _sync(device)
                t2, c2 = time.perf_counter(), time.process_time()
                del out
            if i == 0:
                times[impl]["first_s"] = t2 - t0
            elif i > warmup:
                times[impl]["cpu_s"].append(c2 - c0)
                times[impl]["fwd_s"].append(t1 - t0)
                times[impl]["bwd_s"].append(t2 - t1)
                times[impl]["total_s"].append(t2 - t0)
    for impl in case.impls:
        if steps[impl][1] is None:
            times[impl]["bwd_s"] = None
    return times


def peak_worker() -> dict:
    """Runs inside a one-thread subprocess: this CPU core's memory bandwidth (STREAM-like
    copy and triad, GB/s counting the bytes read and written, no write-allocate) and its
    float32 multiply-add rate (GFLOP/s, 2 per multiply-add) on a chain compiled by
    torch.compile, on a cache-resident array. Best of several repeats: the peak, not a typical value."""
    import torch

    torch.set_num_threads(1)
    n = 1 << 25  # 128 MB per float32 array: far beyond any cache
    a, b, c = torch.rand(n), torch.rand(n), torch.empty(n)

    def best(fn, repeats=7):
        fn()
        ts = []
        for _ in range(repeats):
            t = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t)
        return min(ts)

    copy_s = best(lambda: c.copy_(a))
    triad_s = best(lambda: torch.add(b, a, alpha=3.0, out=c))
    # Multiply-adds per element: far more than its memory operations. Eight independent
    # chains (fused into one loop by torch.compile) so that the FMA latency is hidden and
    # the vector units' throughput binds, as it would for the render's many independent
    # terms; 256 KB of data (L2-resident) make a call ~1e7 multiply-adds, so that its
    # fixed overhead stays small.
    links, chains = 32, 8

    def chain(x, s):
        outs = []
        for c in range(chains):
            y = x
            for _ in range(links):
                y = y * s + (0.5 + c)
            outs.append(y)
        return outs

    x = torch.rand(1 << 16)
    fma_fn = torch.compile(chain, dynamic=False)
    s = torch.tensor(0.999)
    fma_s = best(lambda: fma_fn(x, s), repeats=20)
    return {
        "copy_gbs": 2 * 4 * n / copy_s / 1e9,
        "triad_gbs": 3 * 4 * n / triad_s / 1e9,
        "fma_gflops": 2 * links * chains * x.numel() / fma_s / 1e9,
    }


def compile_worker(modules: list[str]) -> dict:
    """Runs inside a subprocess with $DGRSISE_WARP_CACHE set: per Warp module, the first
    call's time minus a steady call's (compile or cache load), plus Warp's init time."""
    import torch

    torch.set_num_threads(int(os.environ[THREADS_ENV]))
    t0 = time.perf_counter()
    import kernels
    from kernels._warp import ensure_init

    t1 = time.perf_counter()
    ensure_init()
    t2 = time.perf_counter()
    result = {"import_s": t1 - t0, "init_s": t2 - t1, "modules": {}}

    # A trivial kernel first: with an empty cache, Warp's first CPU compile also pays a
    # one-time toolchain/runtime set-up that belongs to no module of ours.
    import warp as wp

    @wp.kernel(module="bench_toolchain_probe")
    def probe(x: wp.array(dtype=float)):
        x[wp.tid()] = 1.0

    probe_arg = wp.zeros(4, dtype=float, device="cpu")
    t = time.perf_counter()
    wp.launch(probe, dim=4, inputs=[probe_arg], device="cpu")
    first = time.perf_counter() - t
    t = time.perf_counter()
    wp.launch(probe, dim=4, inputs=[probe_arg], device="cpu")
    steady = time.perf_counter() - t
    result["modules"]["(warp toolchain, trivial kernel)"] = {
        "first_s": first,
        "steady_s": steady,
        "load_s": first - steady,
    }
    # torch.autograd.grad's first call with grad_outputs imports torch.fx's symbolic
    # shapes (sympy, ~0.25-0.5 s here): pay it now, so that the grad module's first call
    # times the module, not torch.
    warm = torch.ones(2, requires_grad=True)
    torch.autograd.grad(warm * 2, warm, torch.ones(2))
    for module in modules:
        op, dtype_name = module.rsplit("_", 1)
        dtype = {"f32": torch.float32, "f64": torch.float64}[dtype_name]
        if op == "render":
            n = torch.zeros(1, 3, 4, 4, dtype=dtype)
            n[:, 2] = 1
            args = (
                torch.rand(1, 3, 4, 4, dtype=dtype),
                n,
                torch.full((1, 1, 4, 4), 0.5, dtype=dtype),
                torch.rand(1, 3, 4, 4, dtype=dtype),
                torch.tensor([[1.0, 0.0, 4.0]], dtype=dtype),
                torch.tensor([0.0, 0.0, 4.0], dtype=dtype),
            )

            def call(args=args):
                kernels.render(*args)
        elif op == "grad":  # the hand-written map gradients (render backward, maps only)
            n = torch.zeros(1, 3, 4, 4, dtype=dtype)
            n[:, 2] = 1
            maps = [
                torch.rand(1, 3, 4, 4, dtype=dtype),
                n,
                torch.full((1, 1, 4, 4), 0.5, dtype=dtype),
                torch.rand(1, 3, 4, 4, dtype=dtype),
            ]
            maps = [m.requires_grad_() for m in maps]
            light_pos, camera_pos = (
                torch.tensor([[1.0, 0.0, 4.0]], dtype=dtype),
                torch.tensor([0.0, 0.0, 4.0], dtype=dtype),
            )
            out = kernels.render(*maps, light_pos, camera_pos)  # forward module compiled above

            def call(out=out, maps=maps):
                torch.autograd.grad(out, maps, torch.ones_like(out), retain_graph=True)
        else:  # the image module: translate, the row losses and the fused rendering loss
            f, o = torch.rand(1, 2, 4, 4, dtype=dtype), torch.tensor([[0.5, 0.25]], dtype=dtype)

            def call(f=f, o=o):
                kernels.translate(f, o)

        t = time.perf_counter()
        call()
        first = time.perf_counter() - t
        steady = []
        for _ in range(5):
            t = time.perf_counter()
            call()
            steady.append(time.perf_counter() - t)
        result["modules"][module] = {
            "first_s": first,
            "steady_s": statistics.median(steady),
            "load_s": first - statistics.median(steady),
        }
    return result


# ----------------------------------------------------------------------------- driver side
def _spawn(args: list[str], env_extra: dict[str, str], threads: int) -> dict:
    env = dict(os.environ)
    env.update(env_extra)
    env[THREADS_ENV] = str(threads)
    env["OMP_NUM_THREADS"] = str(threads)
    proc = subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), *args], env=env, capture_output=True, text=True
    )
    if proc.returncode != 0:
        raise RuntimeError(f"worker {args} failed:\n{proc.stderr[-4000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _stats(xs: list[float] | None) -> dict | None:
    if not xs:
        return None
    q = statistics.quantiles(xs, n=4) if len(xs) >= 2 else [xs[0]] * 3
    return {"median": statistics.median(xs), "min": min(xs), "max": max(xs), "q1": q[0], "q3": q[2], "n": len(xs)}


def _fmt_ms(s: dict | None) -> str:
    if s is None:
        return "-"
    return f"{s['median'] * 1e3:.1f} [{s['min'] * 1e3:.1f}-{s['max'] * 1e3:.1f}]"


def render_limit(peak: dict, k: int) -> dict:
    """This CPU's forward-render limit (Mpixel-lights/s per core) from the measured peaks:
    the FMA rate over ``RENDER_FWD_FLOPS`` and the triad bandwidth over
    ``render_fwd_bytes(k)``; the smaller one binds."""
    compute = peak["fma_gflops"] * 1e3 / RENDER_FWD_FLOPS
    memory = peak["triad_gbs"] * 1e3 / render_fwd_bytes(k)
    return {"compute_mpl_s": compute, "memory_mpl_s": memory, "limit_mpl_s": min(compute, memory)}


def _ratio(row: dict, impl: str) -> str:
    """Warp's throughput over ``impl``'s (>1: Warp faster), by wall clock, then by process
    CPU time (all threads; on a loaded machine the wall clock also counts the time the
    process waited for a core, the CPU time does not, but it counts torch's OpenMP
    threads spinning)."""
    if impl not in row:
        return "-"
    wall = row["warp"]["throughput"] / row[impl]["throughput"]
    cpu = row[impl]["cpu"]["median"] / row["warp"]["cpu"]["median"]
    return f"{wall:.2f}x ({cpu:.2f}x)"


def markdown(report: dict) -> str:
    meta = report["meta"]
    peak = meta.get("peak")
    lines = [
        f"{meta['cpu']}, {meta['cores']} cores (shared); device {meta['device']}"
        f"{' (' + meta['gpu'] + ')' if meta.get('gpu') else ''}; torch {meta['torch']}, "
        f"warp {meta['warp']}; {meta['date']}. Threads per row: torch.set_num_threads and {THREADS_ENV}. "
        f"Median [min-max] of {meta['repeats']} repeats after {meta['warmup']} warm-up, the implementations "
        f"interleaved in one process; load average (1 min) before and after each case in the last column. "
        "warp/torch, warp/compile: Warp's throughput over the other's (>1: Warp faster) by wall clock, "
        "in brackets by process CPU time (all threads; on a loaded machine the wall clock also counts "
        "waiting for a core).",
    ]
    if str(meta["device"]).startswith("cuda"):
        lines[0] += (
            " On CUDA, 'peak extra MB' is device memory (torch.cuda.max_memory_allocated over one step) and "
            "'CPU ms' the host process's time."
        )
    if peak:
        lim = render_limit(peak, report["cases"][0]["case"]["k"])
        lines += [
            "",
            f"Measured peak, one thread: copy {peak['copy_gbs']:.1f} GB/s, triad {peak['triad_gbs']:.1f} GB/s, "
            f"multiply-add {peak['fma_gflops']:.1f} GFLOP/s. Forward render limit per core at K="
            f"{report['cases'][0]['case']['k']}: {RENDER_FWD_FLOPS} FLOPs -> {lim['compute_mpl_s']:.0f} "
            f"Mpixel-lights/s, {render_fwd_bytes(report['cases'][0]['case']['k']):.0f} bytes -> "
            f"{lim['memory_mpl_s']:.0f}; 'of limit': a forward's throughput over threads x "
            f"{lim['limit_mpl_s']:.0f}, in brackets its pixel-lights per CPU-second over "
            f"{lim['limit_mpl_s']:.0f}.",
        ]
    lines += [
        "",
        "| threads | case | size | impl | fwd ms | bwd ms | fwd+bwd ms | CPU ms | throughput | warp/torch "
        "| warp/compile | compile s | of limit | peak extra MB | load |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in report["cases"]:
        for impl in row["impls"]:
            r = row[impl]
            first = "-"
            if impl == "compile":
                first = f"{r['first_s'] - r['total']['median']:.1f}"
            limit = "-"
            if peak and row["case"]["op"] == "render" and row["case"]["mode"] == "fwd":
                lim = render_limit(peak, row["case"]["k"])["limit_mpl_s"]
                per_cpu_s = row["case"]["b"] * row["case"]["k"] * row["case"]["h"] * row["case"]["w"] / 1e6
                per_cpu_s /= r["cpu"]["median"]
                limit = f"{r['throughput'] / (lim * row['threads']):.1%} ({per_cpu_s / lim:.1%})"
            lines.append(
                f"| {row['threads']} | {row['name']} | {row['size']} | {impl} | {_fmt_ms(r['fwd'])} | "
                f"{_fmt_ms(r['bwd'])} | {_fmt_ms(r['total']) if r['bwd'] else '-'} | "
                f"{r['cpu']['median'] * 1e3:.0f} | {r['throughput']:.1f} {row['unit']} | "
                f"{_ratio(row, 'torch') if impl == 'warp' else ''} | "
                f"{_ratio(row, 'compile') if impl == 'warp' else ''} | {first} | {limit} | "
                f"{r['peak_extra_mb']:.0f} | {row['loadavg_before'][0]:.1f}-{row['loadavg_after'][0]:.1f} |"
            )
    comp = report.get("compile")
    if comp:
        lines += [
            "",
            f"import kernels (and warp) {comp['cold']['import_s']:.2f} s, Warp init {comp['cold']['init_s'] * 1e3:.0f} ms.",
            "",
            "| Warp module | cold compile s | warm load ms | steady call ms |",
            "|---|---|---|---|",
        ]
        for module, cold in comp["cold"]["modules"].items():
            warm = comp["warm"]["modules"][module]
            lines.append(
                f"| {module} | {cold['load_s']:.2f} | {warm['load_s'] * 1e3:.1f} | {warm['steady_s'] * 1e3:.2f} |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="small sizes and few repeats (smoke run)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON results file")
    parser.add_argument(
        "--threads", default=DEFAULT_THREADS, help="comma-separated thread budgets, one row group each (all sides)"
    )
    parser.add_argument("--cases", default=None, help="comma-separated case names (default: all)")
    parser.add_argument("--no-peak", action="store_true", help="skip the bandwidth/FMA peak measurement")
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    parser.add_argument("--repeats", type=int, default=None, help="timed repeats (default 7, quick 3)")
    parser.add_argument("--warmup", type=int, default=None, help="untimed warm-up runs (default 2, quick 1)")
    parser.add_argument("--no-compile", action="store_true", help="skip the compile-time measurement")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument("--compile-worker", help=argparse.SUPPRESS)
    parser.add_argument("--peak-worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    if args.worker:  # subprocess: one case's timings (both sides) or one side's memory
        spec = json.loads(args.worker)
        case = Case(**spec["case"])
        if spec["what"] == "time":
            result = timing_worker(case, spec["device"], spec["warmup"], spec["repeats"])
        else:
            result = memory_worker(case, spec["impl"], spec["device"])
        print(json.dumps(result))
        return result
    if args.peak_worker:
        result = peak_worker()
        print(json.dumps(result))
        return result
    if args.compile_worker:
        result = compile_worker(json.loads(args.compile_worker))
        print(json.dumps(result))
        return result

    import torch
    import warp

    thread_counts = [int(t) for t in str(args.threads).split(",")]
    repeats = args.repeats or (3 if args.quick else 7)
    warmup = args.warmup if args.warmup is not None else (1 if args.quick else 2)
    report = {
        "meta": {
            "threads": thread_counts,
            "device": args.device,
            "quick": args.quick,
            "repeats": repeats,
            "warmup": warmup,
            "torch": torch.__version__,
            "warp": warp.__version__,
            "python": platform.python_version(),
            "cpu": _cpu_name(),
            "gpu": torch.cuda.get_device_name(args.device) if args.device.startswith("cuda") else None,
            "date": time.strftime("%Y-%m-%d %H:%M:%S"),
            "cores": len(os.sched_getaffinity(0)),
            "loadavg_before": os.getloadavg(),
        },
        "cases": [],
    }
    if not args.no_peak:
        report["meta"]["peak"] = _spawn(["--peak-worker"], {}, 1)
    for threads, case in [
        (t, c) for t in thread_counts for c in make_cases(args.quick, args.cases and args.cases.split(","))
    ]:
        row = {
            "name": case.name,
            "threads": threads,
            "size": case.size,
            "unit": case.unit,
            "case": asdict(case),
            "impls": list(case.impls),
            "loadavg_before": os.getloadavg(),
        }
        spec = {"case": asdict(case), "device": args.device, "warmup": warmup, "repeats": repeats}
        timing = _spawn(["--worker", json.dumps({**spec, "what": "time"})], {}, threads)
        for impl in case.impls:
            memory = _spawn(["--worker", json.dumps({**spec, "what": "memory", "impl": impl})], {}, threads)
            raw = timing[impl]
            total = _stats(raw["total_s"])
            row[impl] = {
                "fwd": _stats(raw["fwd_s"]),
                "bwd": _stats(raw["bwd_s"]),
                "total": total,
                "cpu": _stats(raw["cpu_s"]),
                "throughput": case.work / total["median"] / 1e6,
                "first_s": raw["first_s"],
                **memory,
                "raw": raw,
            }
            print(
                f"{threads}t {case.name:28s} {impl:7s} {total['median'] * 1e3:9.1f} ms  "
                f"{row[impl]['throughput']:7.1f} {case.unit}  +{memory['peak_extra_mb']:.0f} MB",
                flush=True,
            )
        row["speedup"] = row["torch"]["total"]["median"] / row["warp"]["total"]["median"]
        if "compile" in row:
            row["speedup_vs_compile"] = row["compile"]["total"]["median"] / row["warp"]["total"]["median"]
        row["loadavg_after"] = os.getloadavg()
        report["cases"].append(row)
        _write(report, args.out)
    report["meta"]["loadavg_after"] = os.getloadavg()

    if not args.no_compile:
        modules = ["render_f32", "grad_f32", "image_f32"]
        if not args.quick:
            modules += ["render_f64", "grad_f64", "image_f64"]
        with tempfile.TemporaryDirectory(prefix="dgrsise-warp-cache-") as cache:
            env = {CACHE_ENV: cache}
            cold = _spawn(["--compile-worker", json.dumps(modules)], env, thread_counts[-1])
            warm = _spawn(["--compile-worker", json.dumps(modules)], env, thread_counts[-1])
        report["compile"] = {"cold": cold, "warm": warm}

    table = _write(report, args.out)
    print()
    print(table)
    print(f"\nwrote {args.out}")
    return report


def _write(report: dict, out: Path) -> str:
    """Write the JSON and its markdown table; return the table. Called after every case
    too, so that a run cut short (a time limit on a lent GPU) keeps the finished rows."""
    out.parent.mkdir(parents=True, exist_ok=True)
    table = markdown(report)
    # Through a temporary file: a run killed mid-write keeps the previous complete file.
    for path, text in ((out, json.dumps(report, indent=2)), (out.with_suffix(".md"), table + "\n")):
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)
    return table


def _cpu_name() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


if __name__ == "__main__":
    main()
