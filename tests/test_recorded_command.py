"""The command line a record holds (``simshear_gym.command_line``): the command's words and the options that differ
from their defaults, in the parser's order; parsing it again gives the same arguments. Fast: parsers only."""

import argparse
import json
import shlex
from pathlib import Path

import pytest

from simshear_gym import cli
from simshear_gym.command_line import command_line, recorded_command

ROOT = Path(__file__).resolve().parents[1]


def toy_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser()
    parser.add_argument("config", type=Path)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--gains", type=float, nargs=2, default=(0.6, 0.2))
    parser.add_argument("--model", action="append", default=None)
    parser.add_argument("--rows", type=int, default=None)
    parser.add_argument("--period-s", type=float, default=0.1)
    parser.add_argument("--out", type=Path, default="results")
    parser.add_argument("--dry-run", action="store_true")
    parser.add_argument("--no-nominal", dest="nominal", action="store_false")
    parser.add_argument("--name", default="servo")
    return parser


def test_defaults_are_left_out_and_the_positional_kept():
    parser = toy_parser()
    args = parser.parse_args(["configs/a.toml", "--seeds", "1", "2", "--gains", "0.6", "0.2", "--out", "results"])
    assert command_line("simshear toy", parser, args) == "simshear toy configs/a.toml"


def test_each_kind_of_option_in_the_parsers_order():
    parser = toy_parser()
    argv = ["--name", "my run", "--dry-run", "--model", "a=x.pt", "--rows", "5", "lab/b.toml", "--seeds", "3",
            "--model", "b={contact}.pt", "--period-s", "0.05", "--no-nominal", "--out", "results/ablations",
            "--gains", "1", "0.123456789"]
    line = command_line("simshear toy", parser, parser.parse_args(argv))
    assert line == ("simshear toy lab/b.toml --seeds 3 --gains 1 0.123456789 --model a=x.pt --model 'b={contact}.pt' "
                    "--rows 5 --period-s 0.05 --out results/ablations --dry-run --no-nominal --name 'my run'")
    assert parser.parse_args(shlex.split(line)[2:]) == parser.parse_args(argv)


def test_paths_stay_as_given_and_missing_arguments_count_as_defaults():
    parser = toy_parser()
    args = argparse.Namespace(config=Path("../shared/x.toml"), out=Path("runs/./eval"), rows=7)
    assert command_line("simshear toy", parser, args) == "simshear toy ../shared/x.toml --rows 7 --out runs/eval"


def test_an_empty_list_is_the_bare_option():
    parser = toy_parser()
    parser.add_argument("--tags", nargs="*", default=["x"])
    assert command_line("simshear toy", parser, parser.parse_args(["a.toml", "--tags"])) == "simshear toy a.toml --tags"


def test_a_flag_that_cannot_hold_the_value_is_one_clear_error():
    parser = toy_parser()
    with pytest.raises(ValueError, match="--dry-run with the value 'yes'"):
        command_line("simshear toy", parser, argparse.Namespace(config="a", dry_run="yes"))


# Real commands: the recorded line, parsed again by the command's own parser, gives the same arguments.
ROUND_TRIPS = [
    ("evaluate", "servo", "--tasks", "colift-heavy", "--objects", "ducky", "brain", "--variants", "shpix2pix",
     "--seeds", "3", "4", "--load-margin-mm", "0", "-0.5", "--out", "results/ablations", "--name", "margin"),
    ("evaluate", "posenet", "--contact", "surface", "--model", "real=runs/pn/{contact}_real/best.pt",
     "--model", "shpix2pix=shipped", "--rows", "50"),
    ("evaluate", "servo6d", "--rows", "panda_servo6d", "--seeds", "--tilt-kp", "0.3"),
    ("evaluate", "env-speed", "--steps", "5", "--num-envs", "2", "--onnx-threads", "1", "2"),
    ("evaluate", "safety-bursts", "--sequences", "10", "--clamp"),
    ("experiment", "tracking", "--rehearsal", "--rig-leader-base", "690", "0", "0", "180", "--period-s", "0.05"),
    ("calibrate-arms", "--fixture", "690", "0", "0", "180", "--out", "runs/arms.json"),
    ("pipeline", "compare", "runs/a", "--reference", "full.json", "--out", "out.json"),
]


def _words(argv: tuple[str, ...]) -> tuple[str, ...]:
    return next(words for words in cli._LEAVES if tuple(argv[:len(words)]) == words)


@pytest.mark.parametrize("argv", ROUND_TRIPS, ids=lambda argv: " ".join(argv[:2]))
def test_a_real_commands_line_parses_back_to_the_same_arguments(argv):
    words = _words(argv)
    parser = cli.command_parser(words)
    args = parser.parse_args(argv[len(words):])
    module = __import__(cli._LEAVES[words], fromlist=["add_arguments"])
    line = recorded_command(" ".join(("simshear", *words)), module.add_arguments, args)
    assert line.startswith(" ".join(("simshear", *words)))
    assert parser.parse_args(shlex.split(line)[1 + len(words):]) == args


def test_options_at_their_defaults_are_left_out_of_a_real_record():
    """The canonical form: results/soak.json's hand-built line named every option at its default; the line recorded
    now is the command alone, which reruns the same soak."""
    from simshear_gym.evaluate import soak

    record = json.loads((ROOT / "results" / "soak.json").read_text())["command"]
    parser = cli.command_parser(("evaluate", "soak"))
    args = parser.parse_args(shlex.split(record)[3:])
    assert record == "simshear evaluate soak --cycles 10000 --seed 0 --period-s 0.02 --mean-gap 20 --threads 1"
    assert recorded_command("simshear evaluate soak", soak.add_arguments, args) == "simshear evaluate soak"


def _recorded_results() -> list[tuple[str, str]]:
    found = []
    for path in sorted((ROOT / "results").rglob("*.json")):
        command = json.loads(path.read_text()).get("command")
        if isinstance(command, str) and command.startswith("simshear ") and "&&" not in command:
            found.append((str(path.relative_to(ROOT)), command))
    return found


@pytest.mark.parametrize("path, command", _recorded_results(), ids=lambda value: value)
def test_the_recorded_results_commands_are_the_canonical_lines_or_rerun_the_same(path, command):
    """Every command in results/ reruns what the canonical line of the same invocation runs; where the hand-built
    line named options at their defaults (``--seed 0``, ``--threads 1``) the canonical line leaves them out."""
    argv = shlex.split(command.split("  #")[0].split(" (")[0])[1:]
    words = _words(tuple(argv))
    parser = cli.command_parser(words)
    args = parser.parse_args(argv[len(words):])
    module = __import__(cli._LEAVES[words], fromlist=["add_arguments"])
    line = recorded_command(" ".join(("simshear", *words)), module.add_arguments, args)
    assert parser.parse_args(shlex.split(line)[1 + len(words):]) == args, path


PACKAGE = ROOT / "simshear_gym"
# Strings that start with a command's words but are no record of this run: a check on another card's line, the
# collection command of the sets the hand-made GDNNs were trained on (cards older than `collect_command`).
NOT_RECORDS = {"simshear pipeline env-model", "simshear collect --replay-all --out runs/paired"}


def _module_name(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts)


def test_no_module_builds_a_command_line_by_hand():
    """A string that starts ``simshear WORDS`` is the first argument of :func:`recorded_command` or of the
    benchmarks' ``write_record``, which passes it on (and those words name a command, recorded from that command's
    own options), a help text or one of :data:`NOT_RECORDS`; no list of words starts with ``"simshear"``."""
    import ast

    hand_built, wrong = [], []
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        words_of_calls, skipped = set(), set()  # the words of recorded_command calls; help texts
        for node in ast.walk(tree):
            if isinstance(node, ast.Call):
                skipped |= {id(part) for kw in node.keywords if kw.arg == "help" for part in ast.walk(kw.value)}
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) in ("recorded_command", "write_record"):
                first, add_arguments = node.args[0], node.args[1]
                if not isinstance(first, ast.Constant):
                    continue  # write_record passing its caller's words on to recorded_command
                words_of_calls.add(id(first))
                words = tuple(first.value.split()[1:])
                module = cli._LEAVES.get(words)
                if module is None or (isinstance(add_arguments, ast.Name) and module != _module_name(path)):
                    wrong.append(f"{path.relative_to(ROOT)}:{node.lineno}: {first.value!r}")
        for node in ast.walk(tree):
            if (isinstance(node, (ast.List, ast.Tuple)) and node.elts and isinstance(node.elts[0], ast.Constant)
                    and node.elts[0].value == "simshear"):
                hand_built.append(f"{path.relative_to(ROOT)}:{node.lineno}: a list of words from 'simshear'")
            text = node.values[0] if isinstance(node, ast.JoinedStr) and node.values else node
            if (isinstance(text, ast.Constant) and isinstance(text.value, str) and text.value.startswith("simshear ")
                    and not {id(node), id(text)} & (words_of_calls | skipped) and text.value not in NOT_RECORDS):
                skipped.add(id(text))
                hand_built.append(f"{path.relative_to(ROOT)}:{node.lineno}: {text.value!r}")
    assert not hand_built, "command lines built by hand (record them with recorded_command):\n" + "\n".join(hand_built)
    assert not wrong, "recorded_command with words of another command:\n" + "\n".join(wrong)
