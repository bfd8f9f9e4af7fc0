"""`results/` is a benchmark record and the README a user's document: checks on the files alone (no data, fast)."""

import glob
import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
MAX_README_LINES = 200
MAX_TOP_LEVEL_JSON = 29  # one canonical file per benchmark command (robot rehearsals, first policy: five more;
# edge following and pushing: two more, and their envs' speed one)
MAX_PNG_BYTES = 500_000

# Canonical files that cannot carry a `command` key honestly: the module that writes them records none.

ABSOLUTE_MARKERS = ("/work/", "/root/", "/home/", "/tmp/", "/Users/", "/mnt/", "/scratch/")
ABSOLUTE_START = re.compile(r"^/(work|root|home|tmp|Users|mnt|scratch|usr|opt|var|srv|data|media)(/|$)")
# A results path in prose: results/NAME.json, results/ablations/NAME.png, results/NAME.{json,png},
# results/servo*.{json,png}, results/translator_*.json.
RESULTS_PATH = re.compile(r"results/[A-Za-z0-9_./*-]*(?:\.(?:json|png)|\.\{json,png\}|\{[a-z_,]+\}\.png)")


def _json_files(recursive: bool) -> list[Path]:
    return sorted(RESULTS.rglob("*.json") if recursive else RESULTS.glob("*.json"))


def _strings(value, where=""):
    """Every string value in a JSON document (and every key), with where it sits."""
    if isinstance(value, dict):
        for key, item in value.items():
            yield f"{where}/{key} (key)", str(key)
            yield from _strings(item, f"{where}/{key}")
    elif isinstance(value, list):
        for index, item in enumerate(value):
            yield from _strings(item, f"{where}[{index}]")
    elif isinstance(value, str):
        yield where, value


def _expand_braces(pattern: str) -> list[str]:
    match = re.search(r"\{([^{}]*)\}", pattern)
    if not match:
        return [pattern]
    return [expanded for option in match.group(1).split(",")
            for expanded in _expand_braces(pattern[:match.start()] + option + pattern[match.end():])]


def test_readme_is_at_most_200_lines():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= MAX_README_LINES, (
        f"README.md has {len(lines)} lines; the research log goes to docs/experiments.md")


def test_at_most_29_json_files_at_the_top_of_results():
    top = _json_files(recursive=False)
    assert len(top) <= MAX_TOP_LEVEL_JSON, (
        f"{len(top)} JSON files at the top of results/; ablations go to results/ablations/: {[p.name for p in top]}")


@pytest.mark.parametrize("path", _json_files(recursive=True), ids=lambda p: str(p.relative_to(RESULTS)))
def test_result_json_parses_and_holds_no_absolute_path(path):
    document = json.loads(path.read_text())
    offending = [(where, text) for where, text in _strings(document)
                 if ABSOLUTE_START.match(text) or any(marker in text for marker in ABSOLUTE_MARKERS)]
    assert not offending, f"{path.name}: absolute paths (write them relative to the repository root): {offending}"


@pytest.mark.parametrize("path", _json_files(recursive=False), ids=lambda p: p.name)
def test_canonical_result_records_its_command(path):
    command = json.loads(path.read_text()).get("command")
    assert isinstance(command, str) and command.startswith("simshear "), f"{path.name} has no `command`"


def test_every_png_in_results_is_under_half_a_megabyte():
    big = {str(p.relative_to(ROOT)): p.stat().st_size for p in RESULTS.rglob("*.png")
           if p.stat().st_size >= MAX_PNG_BYTES}
    assert not big, f"figures of 0.5 MB or more (re-save them smaller): {big}"


@pytest.mark.parametrize("document", ["README.md", "docs/experiments.md"])
def test_results_paths_in_the_docs_exist(document):
    text = (ROOT / document).read_text()
    missing = []
    for mention in sorted(set(RESULTS_PATH.findall(text))):
        for candidate in _expand_braces(mention):
            if not glob.glob(str(ROOT / candidate)):
                missing.append(candidate)
    assert not missing, f"{document} names results files that do not exist: {missing}"


def test_results_paths_named_in_results_exist():
    missing = []
    for path in _json_files(recursive=True):
        for where, text in _strings(json.loads(path.read_text())):
            for mention in RESULTS_PATH.findall(text):
                missing += [f"{path.relative_to(RESULTS)} {where}: {candidate}" for candidate in _expand_braces(mention)
                            if not glob.glob(str(ROOT / candidate))]
    assert not missing, f"results files named in results/ that do not exist: {missing}"
