"""How every entry point reads its command line: absl flags (and ml-collections configs) in a
`FlagValues` of the command's own.

A command is two functions, `define(flag_values)` that declares its flags and `body(options)` that
does the work with typed values, run by `run_command`. The flags live in a fresh `FlagValues` each
time, not in absl's global registry, so any number of commands can be imported and called in one
process (the tests, the demo) without two `--workdir` colliding.

Flag names are written with underscores; each is also accepted with dashes (`--batch_size` and
`--batch-size`), the spelling of the commands recorded before the tools moved to absl.
A usage error (unknown flag, missing or invalid value) prints one line and returns 2, as argparse
did; `--help` prints the command's flags and returns 0.
"""

from __future__ import annotations

import contextvars
import sys
import types
from collections.abc import Callable, Sequence

from absl import flags
from ml_collections import config_flags

HELP_FLAGS = ("-h", "--help", "--helpshort", "--helpfull", "-?")
# The command line being parsed: ml-collections finds a config's `--config.a.b=...` overrides in it
# when the config flag is defined, not when it is parsed.
_ARGV: contextvars.ContextVar[list[str]] = contextvars.ContextVar("argv", default=[])


class UsageError(ValueError):
    """A command line that asks for something impossible: printed as one line, exit status 2."""


def define_config(flag_values: flags.FlagValues, name: str, default: str | None, help_text: str):
    """An ml-collections config file flag (`--NAME=file.py:variant`, overrides `--NAME.a.b=v`)."""
    return config_flags.DEFINE_config_file(name, default, help_text, flag_values=flag_values, lock_config=True,
                                           sys_argv=_ARGV.get())


def definer(flag_values: flags.FlagValues) -> Callable[..., flags.FlagHolder]:
    """`define("integer", "steps", 300, "help", lower_bound=0)`: absl's DEFINE_integer(...) into
    `flag_values`, for a command's flag declarations to read as a table."""
    def define(kind: str, name: str, default, help_text: str, **options) -> flags.FlagHolder:
        if kind == "enum":  # its choices come before the help
            return flags.DEFINE_enum(name, default, options.pop("enum_values"), help_text, flag_values=flag_values,
                                     **options)
        return getattr(flags, f"DEFINE_{kind}")(name, default, help_text, flag_values=flag_values, **options)
    return define


def one_line(error: BaseException) -> str:
    """An error's message on one line: ml-collections' span several, with the config file's own
    traceback inside, and a KeyError's is a repr."""
    text = str(error).replace("\\n", "\n").replace("\\'", "'")
    if "Traceback (most recent call last)" in text:
        head, _, trace = text.partition("Traceback (most recent call last)")
        text = head + [line for line in trace.splitlines() if line.strip()][-1]
    if len(text) > 1 and text[0] == text[-1] and text[0] in "'\"":
        text = text[1:-1]
    return " ".join(text.split())


def dashed_aliases(flag_values: flags.FlagValues) -> None:
    """Accept `--a-b` for every flag `--a_b` (absl's DEFINE_alias, so both set the same value)."""
    for name in list(flag_values):
        dashed = name.replace("_", "-")
        if dashed != name and dashed not in flag_values and "." not in name:
            flags.DEFINE_alias(dashed, name, flag_values=flag_values)


def usage(prog: str, doc: str, flag_values: flags.FlagValues, positional: Sequence[str]) -> str:
    names = "".join(f" {name.upper()}" for name in positional)
    own = _own_flags(flag_values)
    lines = [f"usage: {prog}{names} [--flag=value ...]", "", doc.strip(), "", "flags:"]
    for name, flag in sorted(own.items()):
        default = "" if flag.default is None else f" (default: {flag.default_as_str})"
        spelled = f"[no]{name}" if flag.boolean else name
        lines.append(f"  --{spelled}: {flag.help}{default}")
    lines.append("  --help: show this help and exit")
    if any("_" in name for name in own):
        lines += ["", "A flag's underscores may be written as dashes (--a-b for --a_b)."]
    return "\n".join(lines)


def _own_flags(flag_values: flags.FlagValues) -> dict[str, flags.Flag]:
    """The command's flags by their underscore name (dashed aliases and config overrides left out)."""
    own = {}
    for name in flag_values:
        dashed_alias = "-" in name and name.replace("-", "_") in flag_values
        if not dashed_alias and "." not in name:
            own[name] = flag_values[name]
    return own


def _value(flag: flags.Flag):
    """A flag's value; None for a config flag left unset without a default (ml-collections holds an
    error object there, not None)."""
    if "override_values" in dir(type(flag)):  # an ml-collections config flag (the property raises before parsing)
        if not flag.present and flag.default is None:
            return None
        flag.value.keys()  # a config file that failed to load raises here, not at first use
    return flag.value


def parse(define: Callable[[flags.FlagValues], None], argv: Sequence[str], *, prog: str,
          positional: Sequence[str] = ()) -> types.SimpleNamespace:
    """The flags' values (and positional arguments, by name) of `argv`; raises UsageError."""
    flag_values = flags.FlagValues()
    token = _ARGV.set([prog, *argv])
    try:
        define(flag_values)
    finally:
        _ARGV.reset(token)
    dashed_aliases(flag_values)
    try:
        rest = flag_values([prog, *argv])[1:]
        values = {name: _value(flag) for name, flag in _own_flags(flag_values).items()}
    except flags.Error as error:
        raise UsageError(one_line(error)) from None
    except (AttributeError, KeyError, TypeError, ValueError, OSError) as error:  # ml-collections: a config or override
        raise UsageError(one_line(error)) from None
    if len(rest) != len(positional):
        wanted = " ".join(name.upper() for name in positional) or "no positional arguments"
        raise UsageError(f"expected {wanted}, got {rest}")
    values.update(zip(positional, rest))
    return types.SimpleNamespace(**values)


def run_command(define: Callable[[flags.FlagValues], None], body: Callable[[types.SimpleNamespace], int | None],
                argv: Sequence[str] | None = None, *, prog: str, doc: str, positional: Sequence[str] = ()) -> int:
    """Parse `argv` (default: sys.argv[1:]) with the command's flags and run `body` on the values.

    Returns body's exit status (None counts as 0), 0 after --help, 2 after a usage error."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if any(argument in HELP_FLAGS for argument in argv):
        flag_values = flags.FlagValues()
        define(flag_values)
        print(usage(prog, doc, flag_values, positional))
        return 0
    if not flags.FLAGS.is_parsed():  # absl logging and libraries that read absl's own flags expect it parsed
        flags.FLAGS.mark_as_parsed()
    try:
        options = parse(define, argv, prog=prog, positional=positional)
        status = body(options)
    except UsageError as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 2
    return 0 if status is None else int(status)
