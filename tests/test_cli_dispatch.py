"""Every `rig` subcommand is reachable: listed in the help, its own --help exits 0 and names each of
its options, and it dispatches to a handler; unknown commands and options exit 2 in one line."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from rig.cli import build_parser, main
from rig.cli.commands import COMMANDS as COMMAND_SUMMARIES


def _subcommands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command path, its parser) for every subcommand, nested ones (e.g. `sim servos`) included."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*path, name), sub
                yield from _subcommands(sub, (*path, name))


COMMANDS = list(_subcommands(build_parser()))
IDS = [" ".join(path) for path, _ in COMMANDS]


def test_every_command_module_registers_its_command():
    top = {path[0] for path, _ in COMMANDS}
    assert top == set(COMMAND_SUMMARIES)


def test_top_level_help_lists_every_command(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in COMMAND_SUMMARIES:
        assert f"\n    {name} " in out or f"\n    {name}\n" in out, name


@pytest.mark.parametrize(("path", "parser"), COMMANDS, ids=IDS)
def test_each_command_help_exits_0_and_names_its_options(capsys, path, parser):
    with pytest.raises(SystemExit) as exc:
        main([*path, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: rig {' '.join(path)}")
    options = [s for a in parser._actions for s in a.option_strings]
    assert "--help" in options
    for option in options:
        assert option in out, f"rig {' '.join(path)} --help does not name {option}"
    positionals = [a for a in parser._actions if not a.option_strings]
    for action in positionals:
        if not isinstance(action, argparse._SubParsersAction):
            assert (action.metavar or action.dest) in out


@pytest.mark.parametrize(("path", "parser"), COMMANDS, ids=IDS)
def test_each_command_dispatches_to_a_handler(path, parser):
    nested = any(isinstance(a, argparse._SubParsersAction) for a in parser._actions)
    handler = parser.get_default("handler")
    assert nested or callable(handler), f"rig {' '.join(path)} has no handler"


@pytest.mark.parametrize("argv", [["no-such-command"], ["run", "--no-such-option", "p.yaml"], []])
def test_unknown_command_or_option_exits_2_in_one_line(capsys, argv):
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.strip()


def test_a_command_runs_through_dispatch(capsys, tmp_path):
    data = tmp_path / "fit.csv"
    data.write_text("distance_m,mass_kg\n0.05,3.2\n0.06,2.7\n0.08,2.0\n")
    assert main(["fit", str(data), "--radius-m", "0.01", "--json"]) == 0
    assert '"k"' in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "loaded"),
    [(["--help"], set()), (["fit", "--help"], {"rig.cli.fit"}), (["sim", "--help"], {"rig.cli.sim"})],
)
def test_a_start_up_imports_only_the_command_it_names(argv, loaded):
    """`rig --help` lists every command without importing one; `rig fit` imports no other command."""
    code = (
        "import sys\n"
        "from rig.cli import main\n"
        "from rig.cli.commands import COMMANDS, module_name\n"
        "try:\n"
        f"    main({argv!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        "print(sorted(module_name(c) for c in COMMANDS if module_name(c) in sys.modules), file=sys.stderr)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stderr.strip() == repr(sorted(loaded))
    if argv == ["--help"]:
        assert all(summary[:30] in result.stdout for summary in COMMAND_SUMMARIES.values())
