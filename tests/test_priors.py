"""The priors campaign, ``hnn-pl reproduce --recipe priors``: every model on the state
tasks and the chain pendulum, one record per run, the page rendered from the records
alone, a failed run costing no other; and the docs' inclusion of its tables."""

from __future__ import annotations

import importlib.util
import json
import math
from argparse import ArgumentParser
from pathlib import Path

import pytest

from hnn_pl.commands import reproduce as command
from hnn_pl.commands.cli import quiet_run
from hnn_pl.experiments import priors, results
from hnn_pl.experiments.reproduce import Call, parse

ROOT = Path(__file__).resolve().parent.parent
SWAP = "--model.class_path=hnn_pl.models."


def _call(tmp_path: Path, tasks: list[str], models: list[str], steps: int = 3) -> Call:
    return Call(
        jobs=[],
        recipe="priors",
        out=tmp_path / "P.md",
        json_path=tmp_path / "P.json",
        tasks=tasks,
        models=models,
        seeds=range(1),
        workers=0,
        max_steps=steps,
        command="hnn-pl reproduce --recipe priors",
    )


def _runs(call: Call) -> dict[str, dict]:
    return {r["model"]: r for r in json.loads(call.json_path.read_text())["runs"]}


def test_the_campaign_writes_its_rows_and_the_lagrangian_models_read_the_data_s_system(
    tmp_path,
):
    call = _call(tmp_path, ["spring"], ["baseline", "lnn", "mechanical_lnn"])
    assert priors.run(call, quiet_run) == 0
    runs = _runs(call)
    assert set(runs) == {"baseline", "lnn", "mechanical_lnn"}
    assert runs["baseline"]["config"] == "spring_fast_baseline.yaml"
    assert "options" not in runs["baseline"] and runs["baseline"]["chart"] is None
    for model, name in (("lnn", "LNN"), ("mechanical_lnn", "MechanicalLNN")):
        assert runs[model]["config"] == "spring_fast.yaml"
        assert runs[model]["options"] == [SWAP + name]
        assert runs[model]["chart"] == "MassSpring"  # (q, p) read as (q, q̇) through H
    for r in runs.values():
        assert r["steps"] == 3 and r["train_s"] > 0
        assert math.isfinite(r["energy_mse"]) and math.isfinite(r["state_mse"])
    page = call.out.read_text()
    assert "Smoke run: every run stopped after 3 optimiser steps" in page
    for model in runs:
        assert f"| spring | {model} | 1 | " in page
    # the page is a function of the JSON records alone, rendered by the one renderer
    again = results.render_file(call.json_path, tmp_path / "again.md")
    assert again.read_text() == page


def test_a_failed_run_is_recorded_and_keeps_the_others(tmp_path):
    def lnn_breaks(config: str, options: list[str]):
        if SWAP + "LNN" in options:
            options = [*options, "--model.init_args.hidden_dim=0"]
        return quiet_run(config, options)

    call = _call(tmp_path, ["pendulum"], ["hnn", "lnn"], steps=2)
    assert priors.run(call, lnn_breaks) == 1
    runs = _runs(call)
    assert "hidden_dim" in runs["lnn"]["error"] and "train_s" not in runs["lnn"]
    assert "error" not in runs["hnn"] and math.isfinite(runs["hnn"]["energy_mse"])
    page = call.out.read_text()
    assert "| pendulum | lnn | 0 (1 failed) | — | — | — |" in page
    assert "## Failed runs" in page and "- pendulum fast recipe lnn seed 0: `" in page
    assert "| pendulum | fast recipe | lnn | failed |" in page


@pytest.mark.slow
def test_reproduce_tasks_chain2_runs_the_campaign_beside_the_published_numbers(
    tmp_path, monkeypatch
):
    """Every model on 100 chunks, scored beside the published numbers. Two steps leave
    stiff fields (the Lagrangians' above all): their scoring gets 60 dopri5 steps a
    trajectory instead of 10,000, a row beyond them counting as stopped, and reads the
    first 10 of the 100 test trajectories; the chaos floor, the same for every model,
    is computed once, over all 100 (the protocol's number). Slow tier: the default tier
    has the campaign on the spring (above), the chain pendulum's scores and chaos floor
    (``test_chain_pendulum``) and the page's published numbers (below)."""
    from hnn_pl.data import ChainPendulumData

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(priors, "_FLOORS", {})
    score, floor, floors = ChainPendulumData.rollout_errors, ChainPendulumData.chaos_floor, []
    truth, scored = ChainPendulumData.truth, []

    def budget(self, field, **kwargs):
        t, y = truth(self)
        self.truth = lambda: (t, y[:, :10])
        try:
            errors = score(self, field, **{"max_steps": 60, **kwargs})
        finally:
            del self.truth
        scored.append(errors.shape)
        return errors

    def counted(self, *args, **kwargs):
        floors.append(1)
        return floor(self, *args, **kwargs)

    monkeypatch.setattr(ChainPendulumData, "rollout_errors", budget)
    monkeypatch.setattr(ChainPendulumData, "chaos_floor", counted)
    argv = ["--tasks", "chain2", "--max-steps", "2", "--seeds", "1", "--workers", "0"]
    assert command.main([*argv, "--out", "C.md"]) == 0
    assert len(floors) == 1 and set(scored) == {(10,)}
    data = json.loads((tmp_path / "C.json").read_text())
    assert data["meta"]["recipe"] == "priors" and data["meta"]["max_steps"] == 2
    runs = {r["model"]: r for r in data["runs"]}
    assert set(runs) == set(priors.MODELS) - set(priors.VARIANTS)  # no 100-chunk variant
    assert runs["mechanical_hnn"]["config"] == "chain2_100_mechanical_hnn.yaml"
    assert runs["lnn"]["chart"] == "ChainPendulum"
    for r in runs.values():
        assert r["data"] == "100 chunks" and r["steps"] == 2
        swap = SWAP + priors.CLASSES[r["model"]].rsplit(".")[-1]
        assert r.get("options", [swap]) == [swap] and r["config"].startswith("chain2_100")
        assert 0 < r["rollout_error"] <= 1
        assert r["chaos_floor"] == pytest.approx(5.58e-5, rel=0.01)  # docs/chain_pendulum.md
    page = (tmp_path / "C.md").read_text()
    for model, published in (("baseline", "2.10e-01 (NeuralODE)"), ("hnn", "2.30e-02 (HNN)")):
        assert f"| chain2 | 100 chunks | {model} | 1 | " in page
        assert published in page
    assert "1.25e-02 (DeLaN)" in page and "one value for every row of it): chain2 5.6" in page
    assert ", published 5.70e-05." in page
    assert "## Published numbers" in page and "| 800 | 5.60e-02 | 8.30e-04 |" in page


def test_summaries_are_medians_and_worst_and_the_targets_read_them():
    records = [
        {"task": "chain2", "data": "800 chunks", "model": "hnn", "seed": s, "rollout_error": e}
        for s, e in enumerate((4e-4, 1e-3, 6e-4))
    ]
    records += [{"task": "chain2", "data": "800 chunks", "model": "lnn", "seed": 0, "error": "x"}]
    for r in records[:3]:
        r.update(chaos_floor=5.6e-5, train_s=10.0)
    three = {"task": "chain3", "data": "800 chunks", "model": "hnn", "seed": 0}
    records += [{**three, "rollout_error": 2e-4, "chaos_floor": 9.1e-5, "train_s": 20.0}]
    summary = priors.summarise(records)
    hnn, lnn, hnn3 = summary
    assert hnn["rollout_error"] == (6e-4, 1e-3) and hnn["seeds"] == 3 and hnn["failed"] == 0
    assert lnn["seeds"] == 0 and lnn["failed"] == 1 and "rollout_error" not in lnn
    page = priors.render(records, {"command": "c", "machine": "m", "wall_s": 1.0})
    hnn_target = "- 800 chunks, hnn: 6.00e-04 (target ≤ 8.30e-04, the published HNN): met"
    assert hnn_target + " over 3 of 5 seeds" in page
    assert "- chaos floor: 5.60e-05, 2% from the published 5.70e-05 (target ≤ 30%): met" in page
    assert "Smoke run" not in page
    # 3 links: no published model, its own floor, no targets
    assert hnn3["rollout_error"] == (2e-4, 2e-4)
    assert "| chain3 | 800 chunks | hnn | 1 | 2.00e-04 (2.00e-04) | — | 20 |" in page
    assert "chain2 5.60e-05, published 5.70e-05; chain3 9.10e-05, published 9.51e-05." in page
    assert page.count("- 800 chunks, hnn:") == 1
    fast = {"task": "chain2", "data": "800 chunks", "model": "mechanical_hnn_fast"}
    fast.update(rollout_error=5e-4, chaos_floor=5.6e-5)
    page = priors.render(
        [{**fast, "seed": s, "train_s": t} for s, t in enumerate((560.0, 610.0, 590.0))],
        {"command": "c", "machine": "m", "wall_s": 1.0},
    )
    assert "- 800 chunks, mechanical_hnn_fast, training time: 590 s (target ≤ 600 s" in page
    assert (
        "| chain2 | 800 chunks | mechanical_hnn_fast | 3 | 5.00e-04 (5.00e-04) | 8.30e-04 (HNN)"
        in page
    )


def test_a_lagrangian_model_without_the_data_s_system_is_refused():
    cli = quiet_run("spring_fast.yaml", [SWAP + "LNN"])
    with pytest.raises(RuntimeError, match="no chart"):
        priors.chart_of(cli.model)
    cli.model.attach_system(cli.datamodule.system)
    assert priors.chart_of(cli.model) == "MassSpring"


def test_rows_put_the_costliest_data_first():
    rows = priors.rows(["spring", "chain2"], ["hnn", "lnn"], (100, 800))
    assert [r.data for r in rows] == ["800 chunks"] * 2 + ["100 chunks"] * 2 + ["fast recipe"] * 2
    assert priors.rows(["chain2"])[0] == priors.Row("chain2", "100 chunks", "baseline")
    fast = [r for r in priors.rows(None, None, (100, 800)) if r.model == "mechanical_hnn_fast"]
    assert fast == [priors.Row("chain2", "800 chunks", "mechanical_hnn_fast")]
    assert priors.config_of(fast[0]) == ("chain2_mechanical_hnn_fast.yaml", ())


@pytest.mark.parametrize(
    "argv, recipe, tasks, chunks",
    [
        (["--tasks", "chain2"], "priors", ["chain2"], (100,)),
        (["--tasks", "chain2", "spring", "--chunks", "800", "100"], "priors", None, (100, 800)),
        (["--recipe", "priors"], "priors", None, (100,)),
        (["--tasks", "spring"], "paper", ["spring"], (100,)),
    ],
)
def test_the_recipe_follows_the_tasks(argv, recipe, tasks, chunks, tmp_path):
    call = parse(ArgumentParser(), [*argv, "--out", str(tmp_path / "R.md")])
    assert call.recipe == recipe and call.chunks == chunks
    assert tasks is None or call.tasks == tasks


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--recipe", "paper", "--tasks", "chain2"], "runs in --recipe priors only"),
        (["--tasks", "chain2", "two_body"], "which has no two_body"),
        (["--chunks", "800"], "--chunks belongs to --recipe priors"),
        (["--recipe", "priors", "--models", "dissipative"], "--models dissipative"),
        (["--tasks", "chain2", "--merge"], "--merge belongs"),
    ],
)
def test_bad_priors_calls_are_refused_before_anything_runs(argv, message, capsys):
    with pytest.raises(SystemExit):
        parse(ArgumentParser(prog="reproduce"), argv)
    assert message in capsys.readouterr().err


def _hooks():
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "_hooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_docs_include_the_tables_or_say_they_are_not_yet_measured(tmp_path):
    hooks = _hooks()
    (marker,) = [m for m, (name, _) in hooks.INCLUDES.items() if name == "RESULTS_priors.md"]
    assert marker in (ROOT / "docs" / "priors.md").read_text()
    assert hooks.included(tmp_path, marker).startswith("*Not yet measured: `hnn-pl reproduce")
    record = {"task": "chain2", "data": "100 chunks", "model": "hnn", "seed": 0}
    record.update(rollout_error=1e-2, chaos_floor=5.6e-5, train_s=3.0)
    meta = {"command": "c", "machine": "m", "wall_s": 1.0}
    (tmp_path / "RESULTS_priors.md").write_text(priors.render([record], meta))
    table = hooks.included(tmp_path, marker)
    assert "| chain2 | 100 chunks | hnn | 1 | 1.00e-02 (1.00e-02) | 2.30e-02 (HNN) |" in table
    assert "Per seed" not in table and "Published numbers" not in table
    assert table.endswith("[RESULTS_priors.md](../RESULTS_priors.md).")


@pytest.mark.slow
@pytest.mark.parametrize(
    "task, model, seed",
    [
        ("spring", "mechanical_hnn", 1),
        ("spring", "mechanical_hnn", 3),
        ("pendulum", "mechanical_hnn", 2),
        ("spring", "mechanical_lnn", 3),
    ],
)
def test_the_structured_models_keep_the_energy_on_the_fast_recipes(task, model, seed):
    """With their defaults (``M_θ⁻¹``'s factor ``I + R``, one shared network) the structured
    models train on the fast recipes' high learning rate: energy MSE ≤ 1e-3 on seeds where a
    ``softplus`` diagonal collapsed to ``M_θ = εI`` or the ``M_θ`` form diverged (energy
    MSE 87 to 1.6e4)."""
    record = priors.run_row(priors.Row(task, "fast recipe", model), seed, None, quiet_run)
    assert "error" not in record, record.get("error")
    assert record["energy_mse"] <= 1e-3
