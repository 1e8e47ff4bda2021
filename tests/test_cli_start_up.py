"""What a command's start costs the process (issue 18): ``gcs-pdm --help`` imports no command module,
every command keeps its help line, and the garbage collector's start-up setting is undone."""
from __future__ import annotations

import gc
import os
import subprocess
import sys

import pytest

from gcs_pdm import cli, process_gc

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HEAVY = ("numpy", "numba", "scipy", "pydantic", "pymavlink", "fastapi")


def _modules_after(code: str) -> set[str]:
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys; print(' '.join(sys.modules))"],
                         capture_output=True, text=True, cwd=REPO, env=dict(os.environ, PYTHONPATH=REPO), timeout=60)
    assert out.returncode == 0, out.stderr
    return set(out.stdout.split())


def test_top_level_help_imports_no_command_module():
    code = ("import contextlib, io\nfrom gcs_pdm import cli\n"
            "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n    cli.main(['--help'])")
    loaded = _modules_after(code)
    assert not {m for m in loaded if m.split(".")[0] in HEAVY}, sorted(m for m in loaded if m.split(".")[0] in HEAVY)
    assert not {module for module, _ in cli.COMMANDS.values()} & loaded


@pytest.mark.slow
def test_a_commands_parser_imports_only_its_module():
    loaded = _modules_after("from gcs_pdm import cli\ncli.build_parser('vehicle')")
    assert "gcs_pdm.vehicle_cli" in loaded
    assert not {"gcs_pdm.replay.cli", "gcs_pdm.service.cli", "gcs_pdm.planning.cli", "fastapi"} & loaded


@pytest.mark.parametrize("only", [None, "experiment", "serve"])
def test_every_command_is_listed_with_its_help_line(only):
    parser = cli.build_parser(only)
    listing = parser.format_help()
    for name, (_, summary) in cli.COMMANDS.items():
        assert f"    {name}" in listing and summary.split()[-1] in listing, name
    if only:  # its module registered the real parser (options and func), the others a bare name
        assert parser.parse_args([only] + (["table3"] if only == "experiment" else [])).func
        assert parser.parse_args(["vehicle"]).__dict__.get("func") is None


def test_unknown_command_is_rejected_with_the_choices(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["no-such-command"])
    assert exc.value.code == 2
    assert "invalid choice: 'no-such-command'" in capsys.readouterr().err


def test_start_up_setting_is_undone():
    before = gc.get_threshold()
    with process_gc.command():
        assert gc.get_threshold()[0] == process_gc.START_UP_GC_THRESHOLD
        with process_gc.command():  # nested: the outer one decides
            pass
        assert gc.get_threshold()[0] == process_gc.START_UP_GC_THRESHOLD
        process_gc.start_up_over()
        assert gc.get_threshold() == before and gc.get_freeze_count() > 0
        process_gc.start_up_over()  # once only
    assert gc.get_threshold() == before and gc.get_freeze_count() == 0
    process_gc.start_up_over()  # outside a command: nothing
    assert gc.get_threshold() == before and gc.get_freeze_count() == 0


def test_start_up_setting_is_undone_when_the_command_fails():
    before = gc.get_threshold()
    with pytest.raises(RuntimeError), process_gc.command():
        raise RuntimeError("the command failed")
    assert gc.get_threshold() == before and gc.get_freeze_count() == 0


def test_what_is_left_is_frozen_before_the_interpreters_final_collections():
    code = ("import atexit, contextlib, gc, io\n"
            "atexit.register(lambda: print('at exit', gc.get_freeze_count() > 0))  # runs after gcs_pdm's\n"
            "from gcs_pdm import cli\n"
            "with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
            "    cli.main(['--help'])\n"
            "print('after main', gc.get_freeze_count() > 0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO,
                         env=dict(os.environ, PYTHONPATH=REPO), timeout=60)
    assert out.stdout.split("\n")[:2] == ["after main False", "at exit True"], out.stdout + out.stderr
