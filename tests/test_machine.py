"""What benchmarks and pipeline manifests record of the machine (simshear_gym/machine.py)."""

import torch

from simshear_gym.machine import cpu_model, machine_info


def test_the_machine_is_named_by_its_cpu_model_and_torchs_kernels():
    info = machine_info()
    assert info["cpus"] >= 1 and info["processor"] == cpu_model() != ""
    assert info["torch"] == torch.__version__
    assert info["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability() != ""
