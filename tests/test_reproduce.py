"""The reproduce command on a tiny setting writes a well-formed table and JSON."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

from hnn_pl.commands import reproduce
from hnn_pl.commands.cli_errors import CLIError
from hnn_pl.experiments.results import main as render_main
from hnn_pl.experiments.summary import summarize

ROOT = Path(__file__).resolve().parent.parent


def _run(tmp_path, monkeypatch, extra=()):
    monkeypatch.chdir(tmp_path)
    argv = ["--tasks", "spring", "real_pendulum", "--seeds", "1", "--workers", "0"]
    argv += ["--max-steps", "3", "--out", str(tmp_path / "R.md"), *extra]
    return reproduce.main(argv)


@pytest.mark.slow
def test_tiny_reproduction_writes_markdown_and_json(tmp_path, monkeypatch, capfd):
    assert _run(tmp_path, monkeypatch) == 0
    # one line as each run starts, one as it ends with the time left; no Lightning chatter
    out = capfd.readouterr()
    lines = out.out.splitlines()
    for k in range(1, 5):
        start = next(i for i, line in enumerate(lines) if line.startswith(f"[start {k}/4] "))
        assert lines[start + 1].startswith(f"[done {k}/4, ")
    assert sum(" s left] " in line for line in lines) == 3
    assert "Seed set" not in out.out + out.err and "GPU available" not in out.out + out.err
    md = (tmp_path / "R.md").read_text()
    data = json.loads((tmp_path / "R.json").read_text())
    assert len(data["runs"]) == 4 and not any("error" in r for r in data["runs"])
    # the SIMD kernels torch dispatches to: runs on other kernels may differ in the last bits
    kernels = f"{torch.backends.cpu.get_cpu_capability()} kernels"
    assert kernels in data["meta"]["machine"] and kernels in md
    for r in data["runs"]:
        assert r["steps"] == 3
        for value in (
            r["train_loss"],
            r["test_loss"],
            r["reference"]["energy_mse"],
            r["clean"]["energy_mse"],
        ):
            assert math.isfinite(value) and value >= 0
        assert ("conserved_drift" in r["clean"]) == (r["model"] == "hnn")
    results, long, motion, ratios, per_seed, protocols = md.split("\n## ")[:6]
    names = ("| spring |", "| real_pendulum |")
    assert sum(line.startswith(names) for line in results.splitlines()) == 4
    assert sum(line.startswith(names) for line in ratios.splitlines()) == 2
    assert long.startswith("Long horizons")
    assert sum(line.startswith(names) for line in long.splitlines()) == 4
    assert motion.startswith("Motion")
    assert sum(line.startswith(names) for line in motion.splitlines()) == 4
    for r in data["runs"]:
        clean = r["clean"]
        assert clean["floor_chaos_energy_mse"] >= 0 and clean["valid_time"] > 0
        assert 0 < clean["field_error"] < math.inf and clean["state_mse"] > 0
    assert protocols.startswith("Protocols")
    assert sum(line.startswith(names) for line in per_seed.splitlines()) == 4
    assert "3.593e-02" in md  # the published spring HNN test loss beside ours
    assert "1.09" in md  # the spring quirk is listed in the protocol table


def test_a_failed_run_keeps_the_others(tmp_path, monkeypatch):
    import hnn_pl.evaluation as ev

    real = ev.evaluate_task

    def flaky(task, model, dm, *args, **kwargs):
        if task == "real_pendulum":
            raise RuntimeError("boom")
        return real(task, model, dm, *args, **kwargs)

    monkeypatch.setattr(ev, "evaluate_task", flaky)
    assert _run(tmp_path, monkeypatch, ["--models", "hnn"]) == 1
    data = json.loads((tmp_path / "R.json").read_text())
    assert [("error" in r, r["task"]) for r in data["runs"]] == [
        (False, "spring"),
        (True, "real_pendulum"),
    ]
    md = (tmp_path / "R.md").read_text()
    assert "## Failed runs" in md and "boom" in md
    assert "| spring | hnn | 1 |" in md


def test_merge_keeps_earlier_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    out = str(tmp_path / "R.md")
    common = ["--seeds", "1", "--workers", "0", "--max-steps", "2", "--out", out]
    assert reproduce.main(["--tasks", "real_pendulum", *common]) == 0
    assert reproduce.main(["--tasks", "spring", "--models", "hnn", "--merge", *common]) == 0
    data = json.loads((tmp_path / "R.json").read_text())
    assert sorted((r["task"], r["model"]) for r in data["runs"]) == [
        ("real_pendulum", "baseline"),
        ("real_pendulum", "hnn"),
        ("spring", "hnn"),
    ]
    assert "come from 2 calls of `reproduce --merge`" in (tmp_path / "R.md").read_text()
    assert len(data["meta"]["earlier_calls"]) == 1
    assert reproduce.main(["--tasks", "real_pendulum", "--merge", *common]) == 0
    data = json.loads((tmp_path / "R.json").read_text())
    assert [c["command"] for c in data["meta"]["earlier_calls"]] == [
        "`python -m hnn_pl reproduce --tasks spring --models hnn --merge " + " ".join(common) + "`"
    ], "the first call's runs were all redone, so it no longer appears"


@pytest.mark.slow
def test_tiny_pixel_reproduction_reports_pixel_metrics(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = ["--tasks", "pixel", "--seeds", "1", "--workers", "0", "--max-steps", "2"]
    argv += ["--out", str(tmp_path / "R.md"), "--models-dir", str(tmp_path / "w")]
    # the HNN first, the baseline in a later call: read through the HNN the first one kept
    assert reproduce.main([*argv, "--models", "hnn"]) == 0
    assert reproduce.main([*argv, "--models", "baseline", "--merge"]) == 0
    assert sorted(p.name for p in (tmp_path / "w").iterdir()) == [
        "pixel_baseline_0_paper.pt",
        "pixel_hnn_0_paper.pt",
    ]
    runs = json.loads((tmp_path / "R.json").read_text())["runs"]
    assert sorted(r["model"] for r in runs) == ["baseline", "hnn"]
    for r in runs:
        assert r["reference"]["n_trajectories"] == 1 and r["clean"]["n_trajectories"] > 1
        assert math.isfinite(r["clean"]["pixel_mse"]) and math.isfinite(r["test_loss"])
    assert "| pixel | the reference's evaluation" in (tmp_path / "R.md").read_text()
    # the baseline is read through its seed's HNN, as the reference did; its own kept
    by = {r["model"]: r for r in runs}
    assert by["hnn"]["reference_probe"] == "own" and by["baseline"]["reference_probe"] == "hnn"
    own = by["baseline"]["reference_own_encoder"]["energy_mse"]
    assert math.isfinite(own) and own != by["baseline"]["reference"]["energy_mse"]


@pytest.mark.slow
def test_fast_recipe_records_time_to_accuracy(tmp_path, monkeypatch):
    """``--recipe fast`` runs the fast configs; each run records whether and when its
    energy MSE on the paper's protocol reached the published HNN value (``tta``)."""
    monkeypatch.chdir(tmp_path)
    argv = ["--tasks", "spring", "--models", "hnn", "--seeds", "1", "--workers", "0"]
    assert reproduce.main([*argv, "--recipe", "fast", "--max-steps", "20", "--out", "F.md"]) == 0
    data = json.loads((tmp_path / "F.json").read_text())
    assert data["meta"]["recipe"] == "fast" and len(data["runs"]) == 1
    for r in data["runs"]:
        assert r["steps"] == 20 and "tta" in r
        if r["tta"] is not None:  # reached: at a checked step, below the target
            assert r["tta"]["step"] % 10 == 0 and r["tta"]["energy_mse"] <= 3.8416e-04
    md = (tmp_path / "F.md").read_text()
    assert "recipe `fast`" in md and "time to accuracy" in md
    row = next(line for line in md.splitlines() if line.startswith("| spring | hnn |"))
    assert row.rstrip("|").split("|")[-1].strip().endswith("/1") or "not reached (0/1)" in row


def test_the_dissipative_model_runs_only_where_a_task_has_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    common = ["--seeds", "1", "--workers", "0", "--max-steps", "2", "--out", "R.md"]
    argv = ["--tasks", "spring", "real_pendulum", "--models", "hnn", "dissipative", *common]
    assert reproduce.main(argv) == 0
    runs = json.loads((tmp_path / "R.json").read_text())["runs"]
    assert sorted((r["task"], r["model"]) for r in runs) == [
        ("real_pendulum", "dissipative"),
        ("real_pendulum", "hnn"),
        ("spring", "hnn"),
    ]
    md = (tmp_path / "R.md").read_text()
    row = next(line for line in md.splitlines() if line.startswith("| real_pendulum | dissip"))
    assert row.count("/ —") == 3, row  # no published numbers for this model
    assert "**real_pendulum.**" in md
    with pytest.raises(CLIError, match="no task of"):  # one line from __main__, exit 2
        reproduce.main(["--tasks", "spring", "--models", "dissipative", *common])


def test_no_tta_skips_the_checks_and_says_so(tmp_path, monkeypatch):
    """``--no-tta``: no time-to-accuracy record, the table says "not measured" (not
    "not reached", which would claim a check failed); beside a timed run, the timed one
    alone is counted."""
    monkeypatch.chdir(tmp_path)
    argv = ["--tasks", "spring", "--models", "hnn", "--workers", "0", "--max-steps", "10"]
    argv += ["--recipe", "fast", "--out", "R.md", "--seeds", "1", "--no-tta"]
    assert reproduce.main(argv) == 0
    (run,) = json.loads((tmp_path / "R.json").read_text())["runs"]
    assert run["tta_measured"] is False and "tta" not in run and "tta_history" not in run
    row = next(
        line for line in (tmp_path / "R.md").read_text().splitlines() if "| spring |" in line
    )
    assert row.rstrip("| ").endswith("not measured"), row
    timed = {**run, "seed": 1, "tta_measured": True, "tta": {"seconds": 2.5}}
    (summary,) = summarize([run, timed])
    assert summary["tta"] == "2.5 (2.5) s, 1/1"
    (summary,) = summarize([run, {**timed, "tta": None}])
    assert summary["tta"] == "not reached (0/1)"


@pytest.mark.parametrize(
    "name", ["RESULTS.md", "RESULTS_fast.md", "RESULTS_traj.md", "RESULTS_positions.md"]
)
def test_the_committed_pages_are_their_records_rendered(name, tmp_path, capsys):
    """``python -m hnn_pl.experiments.results X.json`` gives the committed page exactly:
    the pages are generated, never edited by hand."""
    out = tmp_path / name
    assert render_main([str(ROOT / name.replace(".md", ".json")), "--out", str(out)]) == 0
    assert capsys.readouterr().out == f"wrote {out}\n"
    assert out.read_text() == (ROOT / name).read_text()


def test_a_seed_is_found_beside_the_medians():
    """RESULTS_fast.md's spring baseline: median 0.165 over 10 seeds, seed 0's own 2.15
    in its per-seed table."""
    page = (ROOT / "RESULTS_fast.md").read_text()
    assert "| spring | baseline | 10 |" in page and "1.65e-01 (2.15e+00)" in page
    per_seed = page.split("\n## Per seed")[1].split("\n## ")[0]
    rows = [line for line in per_seed.splitlines() if line.startswith("| spring | baseline |")]
    assert len(rows) == 10 and rows[0].split(" | ")[2:6] == [
        "0",
        "3.78e-02",
        "3.76e-02",
        "2.15e+00",
    ]
    assert "Merged with" not in page
