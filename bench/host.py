"""One line on the machine a benchmark ran on: CPU model, cores, whether it multiplies bfloat16 natively."""

from __future__ import annotations

import os
import platform
from pathlib import Path


def host_line() -> str:
    """``AMD EPYC, 2 cores, AVX512-BF16: yes, Python 3.11.7`` (Linux; elsewhere the platform's words)."""
    model, flags = platform.processor() or platform.machine(), set()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        for line in cpuinfo.read_text(errors="replace").splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and value.strip():
                model = value.strip()
            elif key.strip() == "flags":
                flags = set(value.split())
    bf16 = "yes" if "avx512_bf16" in flags else "no"
    return f"{model}, {len(os.sched_getaffinity(0))} cores, AVX512-BF16: {bf16}, Python {platform.python_version()}"
