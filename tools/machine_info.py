"""The machine a benchmark ran on, in one line (every benchmark prints it beside its figures)."""

from __future__ import annotations

import os
import platform
import resource

import cv2
import numpy as np


def cpu_model() -> str:
    """The CPU's model name (from /proc/cpuinfo on Linux), else what ``platform`` knows."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def describe() -> str:
    """CPU, cores, current load, and the versions that matter for speed."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"{platform.platform()}; {cpu_model()}; {os.cpu_count()} logical cores; load average {load:.2f}; "
            f"Python {platform.python_version()}; numpy {np.__version__}; OpenCV {cv2.__version__} "
            f"({cv2.getNumThreads()} threads)")


def peak_rss_kib() -> int:
    """Peak resident memory of this process, KiB: Linux's VmHWM, which starts afresh at exec (``ru_maxrss`` keeps the
    forked parent's size), else ``ru_maxrss``."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
