"""Safe, predictable run folders (campaign names that cannot leave the results folder, --out as the
parent of new runs), campaign files with a byte-order mark, and --set on a field the grid varies."""

from __future__ import annotations

import errno
from pathlib import Path

import pytest
import synthetic_episodes as synth

from mcverify import cli, files, store
from mcverify.campaign import executors, run_folders, runner
from mcverify.campaign.spec import campaign_from_dict, load_campaign
from mcverify.errors import CampaignError

REPO = Path(__file__).resolve().parents[2]

TRAVERSALS = ["../../../etc/evil", "..", ".", "/etc/passwd", "a/b", "a\\..\\b", ".hidden", "~root", "x\x00y",
              "../" * 40 + "deep", "é" * 200, " ._ ", "-", "name with spaces"]


@pytest.mark.parametrize("name", TRAVERSALS)
def test_a_campaign_name_never_leaves_the_results_folder(tmp_path: Path, name: str):
    results = tmp_path / "results"
    camp = campaign_from_dict({"campaign": {"name": name, "seed": 1, "episodes": 1}})
    path = run_folders.default_run_dir(camp, results)
    assert path.parent == results
    assert path.resolve().parent == results.resolve()
    assert not path.name.startswith(".") and "/" not in path.name and "\\" not in path.name and "\x00" not in path.name
    assert len(run_folders.folder_name(name)) <= run_folders.MAX_FOLDER_NAME


def test_folder_names_keep_ordinary_names():
    assert run_folders.folder_name("table2") == "table2"
    assert run_folders.folder_name("eps_sweep-v1.2") == "eps_sweep-v1.2"
    assert run_folders.folder_name("../../../etc/evil") == "etc_evil"
    assert run_folders.folder_name("..") == "campaign"


def test_a_traversal_name_runs_inside_out(tmp_path: Path, monkeypatch):
    """End to end through the command line: `--out DIR` is the parent of the new run folder."""
    (tmp_path / "c.toml").write_text('[campaign]\nname = "../../../evil"\nseed = 1\nepisodes = 1\n')
    monkeypatch.setattr(executors, "simulate", synth.episodes)
    monkeypatch.setattr(runner.executors, "simulate", synth.episodes)
    monkeypatch.setattr(executors, "make_executor", lambda *a, **k: executors.SerialExecutor())
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "deep" / "results"
    assert cli.main(["run", "c.toml", "--out", str(out), "--no-progress"]) == 0
    (run_dir,) = out.iterdir()
    assert run_dir.name.startswith("evil-") and (run_dir / store.MANIFEST).is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml", "deep"]


def test_results_folder_from_the_environment(tmp_path: Path, monkeypatch):
    monkeypatch.setenv(run_folders.ENV_RESULTS_DIR, str(tmp_path / "elsewhere"))
    camp = campaign_from_dict({"campaign": {"name": "x", "seed": 1, "episodes": 1}})
    assert run_folders.default_run_dir(camp).parent == tmp_path / "elsewhere"
    monkeypatch.delenv(run_folders.ENV_RESULTS_DIR)
    assert run_folders.default_run_dir(camp).parent == Path("results")


def test_out_and_run_dir_together_are_refused(tmp_path: Path, capsys):
    code = cli.main(["run", str(REPO / "tests/fixtures/tiny.toml"), "--out", str(tmp_path / "a"),
                     "--run-dir", str(tmp_path / "b")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.startswith("mcverify: error: give --out") and "\n" not in err


def test_a_byte_order_mark_is_accepted(tmp_path: Path):
    text = (REPO / "campaigns" / "smoke.toml").read_text(encoding="utf-8")
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))
    assert load_campaign(path).cells == load_campaign(REPO / "campaigns" / "smoke.toml").cells


GRID = '[campaign]\nname = "g"\nepisodes = 1\n[grid]\n"scenario.front_speed_kmh" = [25, 36]\n' \
       '[axes.method.A]\n"noise.scale" = 1.0\n[axes.method.B]\n"noise.scale" = 2.0\n'


@pytest.mark.parametrize("setting, fragment", [
    ("scenario.front_speed_kmh=30", "is a grid axis"),
    ("scenario.front_speed_mps=8.0", "is a grid axis"),   # the unit alias varies the same field
    ("noise.scale=3.0", "set by the campaign's axis 'method'"),
])
def test_set_on_a_varied_field_is_one_line(tmp_path: Path, capsys, setting, fragment):
    path = tmp_path / "g.toml"
    path.write_text(GRID)
    with pytest.raises(CampaignError, match=fragment):
        load_campaign(path, settings=[setting])
    assert cli.main(["run", str(path), "--set", setting, "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("mcverify: error: --set") and fragment in err and "\n" not in err
    assert not (tmp_path / "r").exists()
    assert len(load_campaign(path, settings=["noise.kind=none"]).cells) == 4  # other fields still settable


def test_a_full_disk_names_the_file(tmp_path: Path, capsys, monkeypatch):
    target = tmp_path / "run" / "summary.json"

    def full(tmp: str) -> None:
        raise OSError("No space left on device")  # as pyarrow raises it: no errno, no file name

    with pytest.raises(OSError) as info:
        files.atomic_write(target, full)
    assert info.value.filename == str(target)
    assert not target.exists() and list(target.parent.iterdir()) == []

    def report(args):
        files.atomic_write(target, lambda tmp: (_ for _ in ()).throw(OSError(errno.ENOSPC, "No space left on device")))

    monkeypatch.setattr(cli, "_cmd_report", report)
    assert cli.main(["report", str(tmp_path / "run")]) == 2
    assert capsys.readouterr().err.strip() == f"mcverify: error: No space left on device: {target}"
