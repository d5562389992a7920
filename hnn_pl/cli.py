"""``python -m hnn_pl {fit,validate,test,predict} --config X.yaml`` (LightningCLI).

Classes are given by their short names (``--model HNN --data SimulatedData
--data.system MassSpring``, ``--model.help HNN``) or by import path: jsonargparse
resolves a short name among the subclasses imported when the parser is built, so this
module imports every model, data module and system (only the full commands load this
module; ``python -m hnn_pl --help`` does not).
"""

from __future__ import annotations

import logging
import os
import warnings
from pathlib import Path
from typing import Any

from lightning.pytorch import LightningDataModule, LightningModule
from lightning.pytorch.cli import (
    ArgsType,
    LightningArgumentParser,
    LightningCLI,
    SaveConfigCallback,
)

# imported for their subclasses: what makes the short class names resolve
from hnn_pl import data, models, systems
from hnn_pl.__main__ import program_name
from hnn_pl.config_paths import resolve_config_args

#: the packages whose classes the CLI knows by their short names
REGISTERED = (models, data, systems)


class _DropTips(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return "LitLogger" not in record.getMessage() and "💡" not in record.getMessage()


def quiet_lightning() -> None:
    """Drop Lightning's advertising tip, its pytree ``LeafSpec`` FutureWarning, its
    warning about ``args`` beside ``sys.argv`` (we pass the resolved argv) and the
    jsonargparse 4.49 deprecations that LightningCLI 2.6 triggers (not ours to fix)."""
    logging.getLogger("lightning.pytorch.utilities.rank_zero").addFilter(_DropTips())
    warnings.filterwarnings("ignore", message=".*LeafSpec.*", category=FutureWarning)
    warnings.filterwarnings("ignore", message=".*LightningCLI's args parameter is intended.*")
    warnings.filterwarnings("ignore", message=".*The dirpath has changed.*")
    os.environ.setdefault("JSONARGPARSE_DEPRECATION_WARNINGS", "off")


class HNNArgumentParser(LightningArgumentParser):
    """Usage lines name the program as it was run (``hnn-pl`` or ``python -m hnn_pl``),
    also in the parsers that ``--model.help X`` builds, instead of ``__main__.py``."""

    def __init__(self, *args, **kwargs) -> None:
        if not args:
            kwargs.setdefault("prog", program_name())
        super().__init__(*args, **kwargs)


def choose_threads(requested: int | str | None = "auto") -> int:
    """Torch threads for this process: ``requested`` if a number; ``"auto"``: the cores
    not busy with other processes, ``max(1, cores − round(load average over 1 min))``.

    On 2 shared cores a second busy process makes 2 OpenMP threads wait for each
    other at every operation (BENCHMARKS.md, threads under load); 1 thread then runs
    as fast as on an idle machine.
    """
    if requested not in (None, "auto"):
        n = int(requested)
        if n < 1:
            raise ValueError(f"threads must be >= 1 or 'auto', got {requested!r}")
        return n
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    try:
        busy = round(os.getloadavg()[0])
    except OSError:
        busy = 0
    return max(1, min(cores or 1, (cores or 1) - busy))


class HNNCLI(LightningCLI):
    """LightningCLI that links the DataModule's ``state_dim`` to the model's ``input_dim``
    and sets torch's thread count (``--threads N|auto``, see :func:`choose_threads`)."""

    def add_arguments_to_parser(self, parser) -> None:
        parser.link_arguments("data.state_dim", "model.init_args.input_dim", apply_on="instantiate")
        parser.add_argument(
            "--threads",
            type=int | str,
            default="auto",
            help="torch threads: a number, or auto (cores not busy with other processes)",
        )

    def parse_arguments(self, parser, args) -> None:
        """Parse, then refuse a ``--ckpt_path`` of another model class than the config's
        (LightningCLI would otherwise build the checkpoint's class under the config's
        run name)."""
        super().parse_arguments(parser, args)
        sub = self.config.get("subcommand")
        config = self.config.get(sub) if sub else None
        ckpt_path = config.get("ckpt_path") if config else None
        if ckpt_path and Path(ckpt_path).is_file():
            _refuse_other_model_class(ckpt_path, config.get("model"))

    def before_instantiate_classes(self) -> None:
        import torch

        config = self.config.get(str(self.subcommand), self.config)
        torch.set_num_threads(choose_threads(config.get("threads", "auto")))
        _refuse_explicit_input_dim(config.get("model"))
        if "weights_only" in config and config["weights_only"] is None:
            config["weights_only"] = True  # a checkpoint cannot run code when loaded


def _class(path: str) -> type:
    import importlib

    module, name = path.rsplit(".", 1)
    return getattr(importlib.import_module(module), name)


def _refuse_other_model_class(ckpt_path: str, model: Any) -> None:
    import torch

    class_path = getattr(model, "class_path", None)
    ckpt = torch.load(ckpt_path, weights_only=True, map_location="cpu")
    saved = ckpt.get("hnn_pl_model_class") or ckpt.get("hyper_parameters", {}).get("_class_path")
    if class_path and saved and _class(saved) is not _class(class_path):
        raise ValueError(
            f"checkpoint {ckpt_path} holds a {saved} but the config builds a {class_path}: "
            "use the config the checkpoint was trained with"
        )


def _refuse_explicit_input_dim(model: Any) -> None:
    """The link from ``data.state_dim`` silently replaces a given ``input_dim``: refuse
    one that differs from the class's default (the only way it can be told apart)."""
    import inspect

    class_path = getattr(model, "class_path", None)
    given = getattr(getattr(model, "init_args", None), "input_dim", None)
    if class_path is None or given is None:
        return
    params = inspect.signature(_class(class_path)).parameters
    if "input_dim" in params and given != params["input_dim"].default:
        raise ValueError(
            f"model.init_args.input_dim = {given}: the model's input size is taken from the "
            "data (its state_dim); remove the option"
        )


def cli_main(args: ArgsType = None, run: bool = True, save_config: bool = True) -> HNNCLI:
    """Run the CLI on ``args`` (``sys.argv[1:]`` when ``None``); returns the CLI object.
    ``save_config=False``: no ``config.yaml`` beside the run (programmatic fits)."""
    import sys

    quiet_lightning()
    args = resolve_config_args(sys.argv[1:] if args is None else list(args))
    return HNNCLI(
        LightningModule,
        LightningDataModule,
        subclass_mode_model=True,
        subclass_mode_data=True,
        args=args,
        run=run,
        save_config_kwargs={"overwrite": True},
        save_config_callback=SaveConfigCallback if save_config else None,
        parser_class=HNNArgumentParser,
    )
