"""Every bundled DataModule satisfies the evaluation's DataModule contract
(:mod:`hnn_pl.evaluation.contract`) after ``setup``: each member present, each method's
parameters named as the protocol's, each attribute of its type."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from hnn_pl.data import (
    ChainPendulumData,
    PixelPendulumData,
    RealPendulumData,
    RecordingData,
    SimulatedData,
)
from hnn_pl.evaluation import ObservedData, PixelData, StateData, SystemData
from hnn_pl.evaluation.contract import members, problems
from hnn_pl.systems import MassSpring, NBody, Pendulum, ThreeBody, TwoBody

STATE = (StateData, SystemData, ObservedData)
SYSTEMS = {"spring": MassSpring, "pendulum": Pendulum, "two_body": TwoBody}
SYSTEMS |= {"three_body": ThreeBody, "nbody": NBody}
#: the DataModules checked below
CHECKED = (SimulatedData, RecordingData, RealPendulumData, PixelPendulumData, ChainPendulumData)
CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_every_datamodule_and_system_of_the_configs_is_checked():
    text = "".join(p.read_text() for p in CONFIGS.glob("*.yaml"))
    named = set(re.findall(r"class_path: hnn_pl\.(data|systems)\.(\w+)", text))
    assert ("data", "SimulatedData") in named and ("systems", "MassSpring") in named
    checked = {("data", c.__name__) for c in CHECKED}
    checked |= {("systems", c.__name__) for c in SYSTEMS.values()}
    assert named <= checked, named - checked


def _satisfies(dm, protocols) -> None:
    for proto in protocols:
        assert isinstance(dm, proto), proto.__name__
        assert problems(dm, proto) == [], proto.__name__


@pytest.mark.parametrize("name", sorted(SYSTEMS))
@pytest.mark.parametrize("observe", ["states", "positions"])
def test_simulated_data_of_each_system(name, observe, tmp_path):
    dm = SimulatedData(
        SYSTEMS[name](), n_trajectories=4, n_points=6, cache_dir=str(tmp_path), observe=observe
    )
    dm.setup()
    _satisfies(dm, STATE)


def _recording(path, n_trajectories: int = 3, n_samples: int = 10):
    """Exact mass-spring states of a few trajectories as a ``.csv`` recording."""
    spring, g = MassSpring(), torch.Generator().manual_seed(0)
    t = torch.linspace(0, 2, n_samples, dtype=torch.float64)
    y = spring.trajectory(spring.sample_initial(n_trajectories, g), t)
    lines = ["trajectory,time,q1,p1"]
    lines += [
        f"{b},{float(t[j])!r},{float(y[j, b, 0])!r},{float(y[j, b, 1])!r}"
        for b in range(n_trajectories)
        for j in range(n_samples)
    ]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def test_recording_data_and_the_real_pendulum(tmp_path):
    path = _recording(tmp_path / "springs.csv")
    for dm in (
        RecordingData(path, MassSpring(), test_trajectories=[1], cache_dir=str(tmp_path)),
        RecordingData(path, test_trajectories=[1], cache_dir=str(tmp_path)),
        RealPendulumData(cache_dir=str(tmp_path)),
    ):
        dm.setup()
        _satisfies(dm, STATE)


def test_chain_pendulum_data(tmp_path):
    dm = ChainPendulumData(n_train=8, n_val=4, n_test=4, n_pool=8, cache_dir=str(tmp_path))
    dm.prepare_data()
    dm.setup()
    _satisfies(dm, STATE)


def test_pixel_data(tmp_path):
    dm = PixelPendulumData(
        n_trajectories=4, n_frames=6, rollout_frames=5, test_fraction=0.5, cache_dir=str(tmp_path)
    )
    dm.setup()
    _satisfies(dm, (StateData, PixelData))


def test_the_check_names_what_a_datamodule_lacks(tmp_path):
    """A missing member, a renamed or default-less parameter and an attribute of another
    type each fail, by name."""

    class Renamed(SimulatedData):
        def reference_inputs(self, count=None):
            return super().reference_inputs(count)

        def rollout_target(self, t_end, n_points=None):
            return super().rollout_target(t_end, n_points)

    dm = Renamed(MassSpring(), n_trajectories=4, n_points=6, cache_dir=str(tmp_path))
    dm.setup()
    assert isinstance(dm, StateData)  # runtime_checkable sees names only
    found = problems(dm, StateData)
    assert len(found) == 2
    assert found[0].startswith("rollout_target: parameter 't_end' needs a default")
    assert found[1].startswith("reference_inputs(count=None): its parameters must begin ['n']")

    good = SimulatedData(MassSpring(), n_trajectories=4, n_points=6, cache_dir=str(tmp_path))
    good.setup()
    names = [k for k in members(StateData) if k != "energy"]
    partial = SimpleNamespace(**{k: getattr(good, k) for k in names} | {"state_dim": "2"})
    assert not isinstance(partial, StateData)
    assert problems(partial, StateData) == ["state_dim: str, not int", "energy: missing"]
