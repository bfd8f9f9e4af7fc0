"""The ``simshear`` command line: lazy (``--help`` of any command imports no torch or pybullet, and the top-level
and group ``--help`` import no command module), every option explained, every command listed."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import subprocess
import sys
import textwrap

import pytest

from simshear_gym import cli

HEAVY = ("torch", "pybullet")
COMMAND_WORDS = [words for words, _, _ in cli.COMMANDS]
GROUPS = sorted({words[:1] for words in COMMAND_WORDS if len(words) > 1})

# One fresh interpreter runs `--help` of every group and every command in turn. An import hook refuses torch and
# pybullet (and records who asked), so each command is judged on its own, not only the first one to pull them in.
_PROBE = textwrap.dedent("""
    import contextlib, importlib.abc, io, json, sys, traceback

    HEAVY = {heavy!r}
    attempts = []

    class Refuse(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in HEAVY:
                importer = next((f"{{f.filename.split('simshear_gym', 1)[-1]}}:{{f.lineno}}"
                                 for f in reversed(traceback.extract_stack()) if "simshear_gym" in f.filename),
                                "?")
                attempts.append(f"{{name}} from simshear_gym{{importer}}")
                raise ModuleNotFoundError(f"{{name}} refused by the lazy-CLI probe", name=name)
            return None

    sys.meta_path.insert(0, Refuse())
    from simshear_gym import cli

    modules = {{module for _, module, _ in cli.COMMANDS}}
    report = {{}}
    for words in [[]] + {groups!r} + {commands!r}:
        attempts.clear()
        out = io.StringIO()
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
                cli.main(words + ["--help"])
            code = "returned without exiting"
        except SystemExit as exit:
            code = exit.code
        except BaseException as error:  # a refused import, or a broken add_arguments
            code = f"{{type(error).__name__}}: {{error}}"
        report[" ".join(words)] = {{
            "exit": code, "heavy_imports": list(attempts),
            "heavy_loaded": [m for m in HEAVY if m in sys.modules],
            "command_modules": sorted(m for m in modules if m in sys.modules),
            "usage": out.getvalue().splitlines()[0] if out.getvalue() else "",
        }}
    print(json.dumps(report))
""")


@pytest.fixture(scope="module")
def help_runs() -> dict:
    """``--help`` of every group and command in one fresh interpreter: exit code, refused heavy imports, the
    command modules loaded so far and the usage line, per command words."""
    script = _PROBE.format(heavy=HEAVY, groups=[list(g) for g in GROUPS], commands=[list(w) for w in COMMAND_WORDS])
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.strip().splitlines()[-1])


def test_top_level_and_group_help_import_no_command_module(help_runs):
    for words in ["", *(" ".join(g) for g in GROUPS)]:
        run = help_runs[words]
        assert run["exit"] == 0, f"simshear {words} --help: {run['exit']}"
        assert run["command_modules"] == [], f"simshear {words} --help imported {run['command_modules']}"
        assert not run["heavy_imports"] and not run["heavy_loaded"]


@pytest.mark.parametrize("words", COMMAND_WORDS, ids=" ".join)
def test_command_help_imports_no_torch_or_pybullet(help_runs, words):
    run = help_runs[" ".join(words)]
    assert not run["heavy_imports"], f"simshear {' '.join(words)} --help imports {run['heavy_imports']}"
    assert run["exit"] == 0, f"simshear {' '.join(words)} --help: {run['exit']}"
    assert run["usage"].startswith(f"usage: simshear {' '.join(words)} ")
    assert not run["heavy_loaded"]


@pytest.mark.parametrize("words", COMMAND_WORDS, ids=" ".join)
def test_every_option_has_help(words):
    parser = cli.command_parser(words)
    bare = [action.option_strings[0] if action.option_strings else action.dest for action in parser._actions
            if not isinstance(action, argparse._HelpAction)
            and (not action.help or not action.help.strip() or action.help == argparse.SUPPRESS)]
    assert not bare, f"simshear {' '.join(words)}: options without help: {bare}"


def _help(argv: list[str]) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as exit:
        cli.main([*argv, "--help"])
    assert exit.value.code == 0
    return " ".join(out.getvalue().split())  # argparse wraps long help lines


def test_help_lists_every_command_with_its_help():
    top = _help([])
    for words, _, help_text in cli.COMMANDS:
        assert f" {words[0]} " in top, f"simshear --help does not name {words[0]!r}"
        if len(words) == 1:
            assert help_text in top
    for group in GROUPS:
        text = _help(list(group))
        for words, _, help_text in cli.COMMANDS:
            if words[:1] == group:
                assert f" {words[1]} {help_text}" in text, f"simshear {group[0]} --help lacks {words[1]!r}"


def test_a_command_imports_only_its_own_module(monkeypatch):
    imported = []
    real_import = cli.importlib.import_module
    monkeypatch.setattr(cli.importlib, "import_module", lambda name: imported.append(name) or real_import(name))
    parser = cli.build_parser(["evaluate", "training-curve", "--run", "a=b"])
    args = parser.parse_args(["evaluate", "training-curve", "--run", "a=b"])
    assert imported == ["simshear_gym.evaluate.training_curve"]
    assert args._module == "simshear_gym.evaluate.training_curve" and args.run == ["a=b"]
    imported.clear()
    cli.build_parser(["--help"]), cli.build_parser(["evaluate"]), cli.build_parser(["no-such-command"])
    assert imported == []


def test_bad_command_and_library_error_exit_codes(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit:
        cli.main(["evaluate", "no-such-command"])
    assert exit.value.code == 2 and "invalid choice" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit:
        cli.main([])
    assert exit.value.code == 2 and "required" in capsys.readouterr().err
    # a library error (here a run directory without history.json) is one line and exit code 2
    assert cli.main(["evaluate", "training-curve", "--run", f"x={tmp_path}", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("simshear: error: ") and "history.json" in err and err.count("\n") == 1


def test_command_parser_rejects_a_group_or_unknown_words():
    with pytest.raises(ValueError, match="no simshear command"):
        cli.command_parser(("evaluate",))


SHIP_COMMANDS = ("translator", "posenet", "onnx", "policy", "run", "recheck-posenet")


def test_ship_help_lists_its_commands_without_importing_them(help_runs):
    run = help_runs["ship"]
    assert run["exit"] == 0 and run["command_modules"] == []
    text = _help(["ship"])
    for word in SHIP_COMMANDS:
        assert f" {word} " in text, f"simshear ship --help does not list {word!r}"
        assert cli._LEAVES[("ship", word)] == f"simshear_gym.ship.{word.replace('-', '_')}"


@pytest.mark.parametrize("old", sorted(cli.ALIASES), ids=" ".join)
def test_an_old_command_is_an_alias_of_its_ship_command(old):
    """The old words run the new command's module (same options, same output) and say whose alias they are."""
    new = cli.ALIASES[old]
    assert new[0] == "ship" and new[1] in SHIP_COMMANDS
    assert cli._LEAVES[old] == cli._LEAVES[new]
    helps = {words: help_text for words, _, help_text in cli.COMMANDS}
    assert helps[old] == f"{helps[new]} (alias of simshear {' '.join(new)}; kept for one release)"
    assert f" {old[1]} {helps[old]}" in _help([old[0]])
    old_parser, new_parser = cli.command_parser(old), cli.command_parser(new)
    assert ([a.option_strings or a.dest for a in old_parser._actions]
            == [a.option_strings or a.dest for a in new_parser._actions])
    argv = {"onnx": ["--weights", "w.pt"], "recheck-posenet": ["w.pt"], "run": ["runs/x"], "policy": ["--run", "r"],
            "translator": ["--run", "r", "--contact", "edge", "--to", "w.pt", "--train-command", "c"],
            "posenet": ["--run", "r", "--contact", "edge", "--to", "w.pt", "--train-command", "c"]}[new[1]]
    old_args = cli.build_parser([*old, *argv]).parse_args([*old, *argv])
    new_args = cli.build_parser([*new, *argv]).parse_args([*new, *argv])
    assert old_args._module == new_args._module
    assert {k: v for k, v in vars(old_args).items() if not k.startswith("command")} == {
        k: v for k, v in vars(new_args).items() if not k.startswith("command")}
