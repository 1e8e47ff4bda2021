"""Every ``gcs-pdm`` command holds to one convention (docs/cli.md): errors as
``gcs-pdm <command>: error: …`` on stderr, exit 2 for a usage or input error (a wrong flag shows
that subcommand's usage), and a file that is no log told as not a MAVLink, DataFlash or ULog log."""
from __future__ import annotations

from pathlib import Path

import pytest

from gcs_pdm.cli import COMMANDS, main
from gcs_pdm.logs.kind import NOT_A_LOG, NotALog, log_kind

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
TLOG = REPO / "fixtures" / "flights" / "learn_01.tlog"

#: every command (and subcommand), as typed
COMMAND_LINES = ["replay", "plan", "experiment", "fit battery", "fit motor", "fit set", "serve", "demo", "sim",
                 "vehicle show", "vehicle check", "vehicle init", "packs ingest", "packs list", "packs show",
                 "packs assign", "signing init"]


def test_every_command_is_listed_here():
    assert {c.split()[0] for c in COMMAND_LINES} == set(COMMANDS)


def _run(argv: list[str], capsys) -> tuple[int, str, str]:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's usage errors
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize("command", COMMAND_LINES)
def test_a_wrong_flag_prints_that_subcommands_usage_and_exits_2(command, capsys):
    code, _, err = _run([*command.split(), "--no-such-flag"], capsys)
    assert code == 2, err
    assert err.startswith(f"usage: gcs-pdm {command}"), err  # not the top level's usage
    assert f"\ngcs-pdm {command}: error: " in err, err


def test_an_unknown_command_is_the_top_levels_usage_error(capsys):
    code, _, err = _run(["nosuch"], capsys)
    assert code == 2 and err.startswith("usage: gcs-pdm") and "gcs-pdm: error: argument COMMAND" in err


def _text_tlog(tmp_path: Path) -> Path:
    path = tmp_path / "notes.tlog"
    path.write_text(README.read_text()[:2000])
    return path


@pytest.mark.parametrize("argv, words", [
    (["replay", "{missing}"], "no such file"),
    (["replay", "{text_bin}"], NOT_A_LOG),
    (["replay", str(README)], NOT_A_LOG),
    (["vehicle", "init", "--from", str(README), "--out", "{out}"], NOT_A_LOG),
    (["vehicle", "init", "--from", "{text_tlog}", "--out", "{out}"], NOT_A_LOG),
    (["vehicle", "init", "--from", "{missing}", "--out", "{out}"], "No such file"),
    (["vehicle", "check", str(README)], "not TOML"),
    (["vehicle", "show", "nosuch"], "neither a preset"),
    (["plan", str(README)], str(README)),
    (["fit", "battery", "--train", "{text_tlog}", "--val", "{text_tlog}", "--test", "{text_tlog}", "--out", "{out}"],
     NOT_A_LOG),
    (["fit", "battery", "--train", str(README), "--val", str(README), "--test", str(README), "--out", "{out}"],
     "unknown flight file type"),
    (["sim", "--vehicle", "nosuch"], "neither a preset"),
    (["serve", "--http", "nonsense"], "expected HOST:PORT"),
    (["demo", "--vehicle", "nosuch"], "neither a preset"),
    (["packs", "--database", "{db}", "show", "nosuch"], "no pack 'nosuch'"),
    (["packs", "--database", "{db}", "ingest", "{empty_dir}"], "no logs found"),
    (["signing", "init", "--key-file", str(README)], "exists"),
], ids=lambda v: " ".join(v[:3]) if isinstance(v, list) else None)
def test_input_errors_are_one_prefixed_line_and_exit_2(argv, words, tmp_path, capsys):
    text_bin = tmp_path / "notes.bin"
    text_bin.write_text("not a DataFlash log")
    names = {"missing": str(tmp_path / "missing.tlog"), "out": str(tmp_path / "out"),
             "text_tlog": str(_text_tlog(tmp_path)), "text_bin": str(text_bin),
             "db": str(tmp_path / "packs.sqlite3"), "empty_dir": str(tmp_path / "empty")}
    (tmp_path / "empty").mkdir()
    argv = [a.format(**names) if a.startswith("{") else a for a in argv]
    code, _, err = _run(argv, capsys)
    words_typed = [a for a in argv if not a.startswith("-") and a != names["db"]]
    command = " ".join(words_typed[:2]) if argv[0] in ("vehicle", "fit", "packs", "signing") else argv[0]
    errors = [line for line in err.splitlines() if ": error: " in line]
    assert code == 2, err
    assert len(errors) == 1 and errors[0].startswith(f"gcs-pdm {command}: error: "), err
    assert words in errors[0], err
    assert "Traceback" not in err


def test_log_kind_reads_the_first_bytes(tmp_path):
    assert log_kind(TLOG) == "tlog"
    ulog = tmp_path / "a.ulg"
    ulog.write_bytes(b"ULog\x01\x12\x35\x01" + bytes(64))
    assert log_kind(ulog) == "ulog"
    dataflash = tmp_path / "a.bin"
    dataflash.write_bytes(b"\xa3\x95\x80" + bytes(64))
    assert log_kind(dataflash) == "dataflash"
    empty = tmp_path / "empty.tlog"
    empty.write_bytes(b"")
    with pytest.raises(NotALog, match="the file is empty"):
        log_kind(empty)
    with pytest.raises(NotALog, match="starts with text"):
        log_kind(README)
    noise = tmp_path / "noise.tlog"
    noise.write_bytes(bytes(range(256)) * 64)  # every magic byte, no packet whose checksum holds
    with pytest.raises(NotALog, match="starts with bytes"):
        log_kind(noise)
