"""Each option is declared once: the training recipe's in RecipeModel, the data options
in TrajectoryDataModule; subclasses forward ``**kwargs`` and still record every option."""

from __future__ import annotations

import inspect

import pytest

from hnn_pl.data import RealPendulumData, RecordingData, SimulatedData
from hnn_pl.data.base import TrajectoryDataModule
from hnn_pl.data.pixel import PixelPendulumData
from hnn_pl.models import HNN, AutoencoderHNN, Baseline, DissipativeHNN
from hnn_pl.models.autoencoder_hnn import AutoencoderDynamicsModel
from hnn_pl.models.base import DynamicsModel
from hnn_pl.models.recipe import RecipeModel
from hnn_pl.systems import Pendulum


def _own(cls: type) -> set[str]:
    """The named parameters of the ``__init__`` ``cls`` defines itself."""
    init = cls.__dict__.get("__init__")
    if init is None:
        return set()
    kinds = (inspect.Parameter.VAR_KEYWORD, inspect.Parameter.VAR_POSITIONAL)
    return {n for n, p in inspect.signature(init).parameters.items() if p.kind not in kinds} - {
        "self"
    }


RECIPE = _own(RecipeModel)
DATA = _own(TrajectoryDataModule)
#: the declarations kept on purpose: the reference's pixel weight decay (1e-5, the
#: recipe's 0), the pixel data's batch of 200 rows (it serves frames, never windows)
KEPT = {
    AutoencoderDynamicsModel: {"weight_decay"},
    PixelPendulumData: {"batch_size", "full_batch_steps", "seed", "cache_dir", "dtype"},
}


def test_the_bases_declare_the_options():
    assert {"lr", "weight_decay", "optimizer", "schedule", "inner_steps"} <= RECIPE
    assert {"batch_size", "seed", "dtype", "window", "keep_fraction", "observe"} <= DATA


MODELS = [DynamicsModel, HNN, Baseline, DissipativeHNN, AutoencoderDynamicsModel, AutoencoderHNN]


@pytest.mark.parametrize("cls", MODELS)
def test_no_model_restates_a_recipe_option(cls):
    assert _own(cls) & RECIPE == KEPT.get(cls, set())


@pytest.mark.parametrize("cls", [SimulatedData, RecordingData, RealPendulumData, PixelPendulumData])
def test_no_datamodule_restates_a_data_option(cls):
    assert _own(cls) & DATA == KEPT.get(cls, set())


@pytest.mark.parametrize("cls", [HNN, Baseline, DissipativeHNN, AutoencoderHNN])
def test_every_model_records_every_recipe_option(cls):
    model = cls(lr=0.25, schedule="cosine")
    assert RECIPE <= set(model.hparams)
    assert model.hparams["lr"] == 0.25 and model.hparams["schedule"] == "cosine"
    assert model.recipe["lr"] == 0.25


def test_the_pixel_model_keeps_the_reference_weight_decay():
    assert AutoencoderHNN().hparams["weight_decay"] == 1e-5
    assert HNN().hparams["weight_decay"] == 0.0


def test_every_datamodule_records_its_options(tmp_path):
    dm = SimulatedData(system=Pendulum(), cache_dir=str(tmp_path), window=3, seed=4)
    assert DATA - {"cache_dir"} <= set(dm.hparams) and dm.hparams["window"] == 3
    assert dm.hparams["seed"] == 4 and dm.hparams["n_points"] == 30
    assert "test_fraction" not in RealPendulumData().hparams  # RecordingData's, not its own
