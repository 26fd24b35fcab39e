"""What the benchmarks record about the machine they ran on (a speed figure holds for the
CPU it names). Imported by the benchmark scripts as a sibling module: they are run as
``python benchmarks/NAME.py``, which puts this folder first on the import path."""

from __future__ import annotations

import platform
from pathlib import Path


def cpu_model() -> str:
    """The CPU's model name from ``/proc/cpuinfo`` (Linux), else what ``platform`` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def machine_meta(threads: int) -> dict:
    """The record every subprocess-per-case benchmark starts its JSON with: CPU, cores,
    torch threads, Python, UTC date and the load average before the runs (the machine
    may be shared; the caller adds ``loadavg_after``)."""
    import os
    import time

    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "threads": threads,
        "python": platform.python_version(),
        "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
        "loadavg_before": os.getloadavg(),
    }
