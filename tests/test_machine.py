"""What benchmarks and pipeline manifests record of the machine (simshear_gym/machine.py)."""

import torch

from simshear_gym.machine import cpu_model, machine_info


def test_the_machine_is_named_by_its_cpu_model_and_torchs_kernels():
    info = machine_info()
    assert info["cpus"] >= 1 and info["processor"] == cpu_model() != ""
    assert info["torch"] == torch.__version__
    assert info["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability() != ""


def test_the_cpus_vector_extensions_come_from_its_flags(tmp_path, monkeypatch):
    from pathlib import Path

    import simshear_gym.machine as machine

    info = machine_info()
    assert set(info["cpu_vector_extensions"]) <= set(machine.VECTOR_FLAGS)
    fake = tmp_path / "cpuinfo"
    fake.write_text("processor\t: 0\nflags\t\t: fpu sse2 avx avx2 fma avx512f avx512bw\n")
    real_path = Path

    def fake_path(name):
        return fake if str(name) == "/proc/cpuinfo" else real_path(name)

    monkeypatch.setattr(machine, "Path", fake_path)
    assert machine.cpu_vector_extensions() == ["avx2", "fma", "avx512f", "avx512bw"]
    fake.write_text("processor\t: 0\nflags\t\t: fpu sse2 avx avx2 fma\n")  # an AVX2 laptop
    assert machine.cpu_vector_extensions() == ["avx2", "fma"]
