"""The lock of exact versions (``constraints.txt``) covers every dependency the package names, and benchmark
records name the versions they ran with."""

import re
import tomllib
from pathlib import Path

from simshear_gym.machine import RECORDED_PACKAGES, machine_info, package_versions

ROOT = Path(__file__).resolve().parents[1]


def canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def pins() -> dict[str, str]:
    lines = [line.strip() for line in (ROOT / "constraints.txt").read_text().splitlines()]
    entries = [line for line in lines if line and not line.startswith("#")]
    assert all(re.fullmatch(r"[A-Za-z0-9_.\-]+==[A-Za-z0-9_.]+", line) for line in entries), entries
    return {canonical(line.split("==")[0]): line.split("==")[1] for line in entries}


def test_constraints_pin_every_dependency_and_extra_of_the_package_but_not_the_package():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    required = project["dependencies"] + project["optional-dependencies"]["test"]
    names = {canonical(re.split(r"[<>=!~\[ ;]", spec, maxsplit=1)[0]) for spec in required}
    pinned = pins()
    assert names <= set(pinned), sorted(names - set(pinned))
    assert "simshear-gym" not in pinned and "+" not in pinned["torch"]  # a local version no index serves


def test_records_name_python_and_the_package_versions():
    versions = package_versions()
    assert set(versions) == {"python", *RECORDED_PACKAGES}
    assert versions["torch"] and versions["numpy"] and versions["python"].count(".") == 2
    assert machine_info()["packages"] == versions
