"""The README's two commands stay the ones CI runs and the ones that exist."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    ci_command = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert ci_command in readme, f".ci/run's command {ci_command!r} is not the README's"


def test_readme_main_command_names_an_existing_subcommand():
    from simshear_gym.cli import COMMANDS

    readme = (ROOT / "README.md").read_text()
    assert "&& .venv/bin/simshear demo" in readme
    assert ("demo",) in {words for words, _, _ in COMMANDS}
