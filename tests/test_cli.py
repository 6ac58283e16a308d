"""The command line's small contracts: --version, help for `kernels`, SIGTERM handled like Ctrl-C."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

import mcverify
from mcverify import cli


def test_version_prints_the_package_version(capsys):
    assert cli.main(["--version"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"mcverify {mcverify.__version__}")
    assert len(out.splitlines()) == 1


def test_kernels_without_an_action_prints_the_kernels_help(capsys):
    assert cli.main(["kernels"]) == 2
    out = capsys.readouterr().out
    assert out.startswith("usage: mcverify kernels")
    assert "list" in out and "clear" in out
    assert "estimate" not in out, "the top-level help, not the kernels one"


def test_the_user_commands_and_no_benchmark(capsys):
    """The benchmarks are ``python -m benchmarks.NAME``, not commands of the installed tool."""
    assert cli.main(["--help"]) == 0
    out = capsys.readouterr().out
    for command in ("run", "estimate", "replay", "report", "compare", "falsify", "fields", "kernels"):
        assert f"\n    {command} " in out
    assert "bench" not in out


@pytest.mark.parametrize("sig, code, word", [(signal.SIGTERM, 143, "terminated (SIGTERM)"),
                                             (signal.SIGINT, 130, "interrupted")])
def test_sigterm_and_ctrl_c_print_the_resume_hint(tmp_path: Path, capsys, monkeypatch, sig, code, word):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "manifest.json").write_text("{}")

    def fake_run(args):  # stands for a run in progress: the run folder exists, then the signal arrives
        args.run_dir = run_dir
        os.kill(os.getpid(), sig)
        time.sleep(10)
        raise AssertionError("the signal did not interrupt the run")

    monkeypatch.setattr(cli, "_cmd_run", fake_run)
    # A shell without job control starts background jobs with SIGINT ignored, and Python then installs
    # no KeyboardInterrupt handler; give the process what a terminal's Ctrl-C reaches.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        assert cli.main(["run", "whatever.toml"]) == code
    finally:
        signal.signal(signal.SIGINT, previous)
    err = capsys.readouterr().err.strip()
    assert err == f"mcverify: {word}; finished chunks are kept (mcverify run --resume {run_dir})"


@pytest.mark.parametrize("command, marker", [("falsify", "falsify.json"), ("estimate", "manifest.json")])
def test_the_resume_hint_names_the_command_that_made_the_folder(tmp_path: Path, capsys, monkeypatch, command, marker):
    folder = tmp_path / "search"
    folder.mkdir()
    (folder / marker).write_text("{}")

    def fake_command(args):
        args.run_dir = folder
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, f"_cmd_{command}", fake_command)
    assert cli.main([command, "whatever.toml"]) == 130
    err = capsys.readouterr().err.strip()
    assert err == f"mcverify: interrupted; finished chunks are kept (mcverify {command} --resume {folder})"


def test_a_signal_before_the_run_folder_exists_gives_no_resume_hint(tmp_path: Path, capsys, monkeypatch):
    def fake_run(args):
        args.run_dir = tmp_path / "not-yet"
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(10)

    monkeypatch.setattr(cli, "_cmd_run", fake_run)
    assert cli.main(["run", "whatever.toml"]) == 143
    assert capsys.readouterr().err.strip() == "mcverify: terminated (SIGTERM)"


def test_sigterm_handler_is_restored_after_the_command(monkeypatch):
    before = signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(cli, "_cmd_kernels_list", lambda args: 0)
    assert cli.main(["kernels", "list"]) == 0
    assert signal.getsignal(signal.SIGTERM) is before
