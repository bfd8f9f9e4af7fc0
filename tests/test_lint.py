"""ruff (pycodestyle, pyflakes, import order, pyupgrade; settings in pyproject.toml) passes on the package and
the tests, so that CI, which runs this suite, lints too."""

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_passes():
    ruff = shutil.which("ruff", path=str(Path(sys.executable).parent)) or shutil.which("ruff")
    assert ruff, "ruff is not installed: it is in the test extras (pip install -e '.[test]')"
    result = subprocess.run([ruff, "check", "--no-cache", "simshear_gym", "tests"], cwd=ROOT,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
