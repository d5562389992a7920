"""examples/camera.py: a complete config that trains on a trajectory,time,q CSV."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import torch
import yaml

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "camera.py"


def _example():
    spec = importlib.util.spec_from_file_location("camera_example", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_camera_config_trains_on_angles_alone(tmp_path):
    config = _example().main(steps=20, folder=str(tmp_path))
    header = (tmp_path / "angles.csv").read_text().splitlines()[0]
    assert header == "trajectory,time,q"
    assert yaml.safe_load(config.read_text())["data"]["class_path"] == "hnn_pl.data.RecordingData"
    run = tmp_path / "lightning_logs" / "camera_hnn" / "version_0"
    ckpt = torch.load(run / "checkpoints" / "last.ckpt", weights_only=False, map_location="cpu")
    states = ckpt["state_dict"]["states"]
    assert states.shape == (9 * 40, 2)  # 9 training swings of 40 angles, (q, p) learned
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(run)).Reload()
    mse = events.Scalars("rollout/position_mse")[-1].value
    assert math.isfinite(mse) and mse > 0
