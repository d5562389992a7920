"""Every script in examples/ imports and runs as a user runs it (small sizes): it writes
only where it is told or into a temporary folder, and prints no third-party advert or
deprecation notice; what a script's run leaves is checked too (:data:`CHECKS`)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest
from forks import Forks

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

#: each example's command-line arguments for a quick run (``{out}``: a temporary folder)
QUICK: dict[str, list[str]] = {
    "double_well.py": [],
    "recording.py": ["20", "{out}"],
    "camera.py": ["20", "{out}"],
    "figures.py": ["--steps", "5", "--out", "{out}"],
    "friction.py": ["--steps", "3", "--seeds", "1", "--out", "{out}"],
}

#: what each quick run leaves in its folder
WRITES: dict[str, set[str]] = {
    "double_well.py": set(),
    "recording.py": {"springs.csv"},
    "camera.py": {"angles.csv", "camera.yaml", "lightning_logs"},
    "figures.py": {"bump.png", "bump.pt", "double_well.png"},
    "friction.py": {"friction_table.md", "friction.png"},
}


def _camera_trained_on_angles_alone(out: Path) -> None:
    """camera.py: a complete config that trains on a ``trajectory,time,q`` CSV, the
    momenta learned, and scores the held-out swings by their positions."""
    import math

    import torch
    import yaml
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    assert (out / "angles.csv").read_text().splitlines()[0] == "trajectory,time,q"
    config = yaml.safe_load((out / "camera.yaml").read_text())
    assert config["data"]["class_path"] == "hnn_pl.data.RecordingData"
    run = out / "lightning_logs" / "camera_hnn" / "version_0"
    ckpt = torch.load(run / "checkpoints" / "last.ckpt", weights_only=False, map_location="cpu")
    assert ckpt["state_dict"]["states"].shape == (9 * 40, 2)  # 9 training swings of 40 angles
    mse = EventAccumulator(str(run)).Reload().Scalars("rollout/position_mse")[-1].value
    assert math.isfinite(mse) and mse > 0


#: what a quick run's folder must hold beyond its files' names
CHECKS = {"camera.py": _camera_trained_on_angles_alone}

#: what no example may print (Lightning's cloud advert, deprecation notices)
NOISE = ("litlogger", "LitLogger", "💡", "deprecated", "Deprecat")


def test_every_example_is_listed():
    assert sorted(p.name for p in EXAMPLES.glob("*.py")) == sorted(QUICK) == sorted(WRITES)


@pytest.mark.parametrize("name", sorted(QUICK))
def test_example_imports(name):
    spec = importlib.util.spec_from_file_location(f"example_{name[:-3]}", EXAMPLES / name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert name == "double_well.py" or callable(module.main)


def test_the_double_well_is_a_system_from_h_alone():
    sys.path.insert(0, str(EXAMPLES))
    try:
        from double_well import DoubleWell
    finally:
        sys.path.remove(str(EXAMPLES))
    import torch

    y = torch.tensor([[0.5, 0.3]], dtype=torch.float64)
    # dq/dt = ∂H/∂p = p, dp/dt = −∂H/∂q = −q(q² − 1)
    expected = torch.tensor([[0.3, -0.5 * (0.25 - 1)]], dtype=torch.float64)
    torch.testing.assert_close(DoubleWell().vector_field(0.0, y), expected)


@pytest.fixture(scope="module")
def forks(tmp_path_factory):
    """One fork server (``tests/cli_forks.py``, one thread as the examples ask) for the
    scripts, and the file of what it printed itself while it imported the package."""
    log = tmp_path_factory.mktemp("forks") / "imports.log"
    server = Forks(log, env={"OMP_NUM_THREADS": "1"})
    yield server, log
    server.close()


def test_importing_what_the_examples_import_prints_nothing(forks, tmp_path):
    """The fork server's own imports (torch, Lightning, the package: what a script's
    imports would print, which its forked run does not repeat) printed no noise."""
    server, log = forks
    code, _ = server.run([], tmp_path, {}, [], tmp_path, script=EXAMPLES / "double_well.py")
    assert code == 0
    printed = log.read_text()
    assert not [word for word in NOISE if word in printed], printed


@pytest.mark.parametrize("name", sorted(QUICK))
def test_example_runs_as_a_script(name, tmp_path, forks):
    """``python examples/NAME ARGS`` from an empty directory (in a forked child of the
    fork server: the imports are paid once)."""
    out, cwd = tmp_path / "out", tmp_path / "cwd"
    cwd.mkdir()
    args = [a.format(out=out) for a in QUICK[name]]
    code, stderr = forks[0].run(args, cwd, {}, [], tmp_path, script=EXAMPLES / name)
    assert code == 0, stderr
    printed = (tmp_path / "stdout").read_text() + stderr
    assert not [word for word in NOISE if word in printed], printed
    assert list(cwd.iterdir()) == [], "an example wrote into the directory it was run from"
    assert {p.name for p in out.iterdir()} == WRITES[name] if WRITES[name] else not out.exists()
    if name in CHECKS:
        CHECKS[name](out)
