"""What a benchmark or a pipeline run records of the machine it ran on, so that wall times from two machines can be
told apart: the CPU count and model, and the instruction set torch's CPU kernels use (training on two CPUs with
different kernels gives different bits: docs/experiments.md, pipeline_full_tactip331_slow_cpu)."""

from __future__ import annotations

import os
import platform
from pathlib import Path


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux), else what :mod:`platform` knows (e.g. ``x86_64``)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_info() -> dict:
    """``cpus``, ``processor`` (:func:`cpu_model`), ``torch`` (its version) and ``torch_cpu_capability`` (the
    instruction set of torch's CPU kernels: ``AVX2``, ``AVX512``, ``DEFAULT``, ...)."""
    import torch

    return {"cpus": os.cpu_count(), "processor": cpu_model(), "torch": torch.__version__,
            "torch_cpu_capability": torch.backends.cpu.get_cpu_capability()}
