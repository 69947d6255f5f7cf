"""The one command-line convention (kosmos_jax/commands.py): absl flags in a FlagValues per command."""

import ast
import pathlib

import pytest
from absl import flags

from kosmos_jax import commands

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "kosmos_jax"


def define(flag_values):
    commands.define_config(flag_values, "config", None, "a config file")
    define_flag = commands.definer(flag_values)
    define_flag("string", "workdir", None, "a folder")
    define_flag("integer", "batch_size", 16, "examples", lower_bound=1)
    define_flag("bool", "json", False, "one line")
    define_flag("enum", "scheme", "fairseq", "ids", enum_values=["fairseq", "native"])
    flags.mark_flag_as_required("workdir", flag_values=flag_values)


def run(argv, seen=None, positional=()):
    def body(options):
        if seen is not None:
            seen.append(options)
        return 0
    return commands.run_command(define, body, argv, prog="prog", doc="What it does.\n\nMore.", positional=positional)


def test_flags_parse_with_underscores_or_dashes_and_configs_take_overrides():
    seen = []
    assert run(["--workdir=w", "--batch-size", "3", "--json", "--scheme=native",
                "--config=configs/kosmos_e.py:tiny", "--config.train.steps=7"], seen) == 0
    assert run(["--workdir", "w2", "--batch_size=5", "--nojson"], seen) == 0
    first, second = seen
    assert (first.workdir, first.batch_size, first.json, first.scheme) == ("w", 3, True, "native")
    assert first.config.train.steps == 7
    assert (second.workdir, second.batch_size, second.json, second.config) == ("w2", 5, False, None)


@pytest.mark.parametrize("argv, message", [
    ([], "flag --workdir=None: Flag --workdir must have a value other than None."),
    (["--workdir=w", "--batch_sizes=3"], "Unknown command line flag 'batch_sizes'. Did you mean: batch_size ?"),
    (["--workdir=w", "--batch-size=0"], "flag --batch_size=0: 0 is not a positive integer"),
    (["--workdir=w", "--scheme=other"], "flag --scheme=other: value should be one of <fairseq|native>"),
    (["--workdir=w", "stray"], "expected no positional arguments, got ['stray']"),
    (["--workdir=w", "--config=configs/no_such_file.py"], "No such file or directory"),
    (["--workdir=w", "--config=configs/kosmos_e.py:no_such_variant"], "no_such_variant"),
    (["--workdir=w", "--config=configs/kosmos_e.py:tiny", "--config.train.stepz=1"], 'Did you mean "steps"'),
])
def test_a_bad_command_line_is_one_line_and_status_2(argv, message, capsys):
    assert run(argv) == 2
    error = capsys.readouterr().err.splitlines()
    assert len(error) == 1 and error[0].startswith("prog: error: ") and message in error[0], error


def test_help_lists_the_flags_and_returns_0(capsys):
    assert run(["--workdir=w", "--help"]) == 0
    shown = capsys.readouterr().out
    assert shown.startswith("usage: prog [--flag=value ...]\n\nWhat it does.\n\nMore.")
    for line in ("  --batch_size: examples (default: '16')", "  --workdir: a folder", "  --[no]json: one line (default: 'false')",
                 "  --help: show this help and exit"):
        assert line in shown.splitlines()
    assert "--batch-size:" not in shown and "dashes" in shown  # aliases are said once, not listed


def test_positional_arguments_are_named():
    seen = []
    assert run(["ROOT", "--workdir=w"], seen, positional=("root",)) == 0
    assert seen[0].root == "ROOT"
    assert run(["--workdir=w"], seen, positional=("root",)) == 2


def test_commands_share_no_flag_registry():
    """Two commands with the same flags parse in one process, and absl's global registry gains nothing."""
    before = set(flags.FLAGS)
    seen = []
    assert run(["--workdir=a"], seen) == 0 and run(["--workdir=b", "--batch_size=2"], seen) == 0
    assert [o.workdir for o in seen] == ["a", "b"] and seen[0].batch_size == 16
    assert set(flags.FLAGS) == before


def test_body_status_and_usage_errors_from_the_body():
    def body(options):
        raise commands.UsageError("--workdir and --json do not go together")
    assert commands.run_command(define, body, ["--workdir=w"], prog="p", doc="d") == 2
    assert commands.run_command(define, lambda options: 3, ["--workdir=w"], prog="p", doc="d") == 3
    assert commands.run_command(define, lambda options: None, ["--workdir=w"], prog="p", doc="d") == 0


def test_every_entry_point_follows_the_convention():
    """No module of the package parses a command line with argparse or absl's global app.run."""
    offenders = []
    for path in sorted(PACKAGE.rglob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = ([alias.name for alias in node.names] if isinstance(node, ast.Import) else
                     [f"{node.module}.{alias.name}" for alias in node.names] if isinstance(node, ast.ImportFrom)
                     else [])
            if any(name == "argparse" or name.startswith("absl.app") or name == "absl.app" for name in names):
                offenders.append(str(path.relative_to(PACKAGE)))
    assert offenders == []
