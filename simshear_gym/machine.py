"""What a benchmark or a pipeline run records of the machine it ran on, so that wall times from two machines can be
told apart: the CPU count and model, the instruction set torch's CPU kernels use (training on two CPUs with
different kernels gives different bits: docs/experiments.md, pipeline_full_tactip331_slow_cpu), and the versions
of Python and of the packages that make the figures (``constraints.txt`` at the repository root pins the set the
records were measured with)."""

from __future__ import annotations

import os
import platform
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

#: the distributions whose versions a record names: the package and what its figures run on
RECORDED_PACKAGES = ("simshear-gym", "numpy", "scipy", "pandas", "scikit-image", "opencv-python-headless",
                     "pybullet", "gymnasium", "torch", "onnxruntime", "stable-baselines3", "sb3-contrib",
                     "matplotlib")


def _cpuinfo(key: str) -> str | None:
    """The value of the first ``/proc/cpuinfo`` line that starts with ``key`` (None: no such line, or no such file)."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
    except OSError:
        return None
    return next((line.split(":", 1)[1] for line in lines if line.startswith(key)), None)


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux), else what :mod:`platform` knows (e.g. ``x86_64``)."""
    model = _cpuinfo("model name")
    return model.strip() if model is not None else platform.processor() or platform.machine()


VECTOR_FLAGS = ("avx2", "fma", "avx_vnni", "avx512f", "avx512bw", "avx512_vnni", "avx512_bf16", "amx_tile")
"""The CPU flags that decide which kernels ONNX Runtime and torch pick (AVX2 laptops against AVX-512 servers)."""


def cpu_vector_extensions() -> list[str]:
    """Which of :data:`VECTOR_FLAGS` the CPU has (``/proc/cpuinfo``'s flags on Linux; empty where unknown)."""
    flags = set((_cpuinfo("flags") or "").split())
    return [name for name in VECTOR_FLAGS if name in flags]


def package_versions() -> dict[str, str | None]:
    """``python`` and each of :data:`RECORDED_PACKAGES`' installed version (None: not installed)."""
    versions: dict[str, str | None] = {"python": platform.python_version()}
    for name in RECORDED_PACKAGES:
        try:
            versions[name] = version(name)
        except PackageNotFoundError:
            versions[name] = None
    return versions


def machine_info() -> dict:
    """``cpus``, ``processor`` (:func:`cpu_model`), ``cpu_vector_extensions`` (:func:`cpu_vector_extensions`),
    ``torch`` (its version), ``torch_cpu_capability`` (the
    instruction set of torch's CPU kernels: ``AVX2``, ``AVX512``, ``DEFAULT``, ...) and ``packages``
    (:func:`package_versions`)."""
    import torch

    return {"cpus": os.cpu_count(), "processor": cpu_model(), "cpu_vector_extensions": cpu_vector_extensions(),
            "torch": torch.__version__, "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
            "packages": package_versions()}
