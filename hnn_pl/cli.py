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
from hnn_pl.cli_errors import (
    CLIError,
    check_checkpoint,
    check_ckpt_path,
    check_starts,
    check_threads,
    checkpoint_init_args,
    loaded_class,
    one_line,
)
from hnn_pl.config_paths import resolve_config_args
from hnn_pl.safe_io import load_checkpoint

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

    def error(self, message: str, ex: Exception | None = None):
        """A parse error of the command line is one line (:func:`cli_errors.one_line`),
        no usage dump; parsers that do not exit on errors raise as before."""
        if not self.exit_on_error:
            return super().error(message, ex)
        raise CLIError(one_line(message, self)) from None


def choose_threads(requested: int | str | None = "auto") -> int:
    """Torch threads for this process: ``requested`` if a number; ``"auto"``: the cores
    not busy with other processes, ``max(1, cores − round(load average over 1 min))``.

    On 2 shared cores a second busy process makes 2 OpenMP threads wait for each
    other at every operation (BENCHMARKS.md, threads under load); 1 thread then runs
    as fast as on an idle machine.
    """
    n = check_threads(requested)
    if n is not None:
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

    def _parse_ckpt_path(self) -> None:
        """A ``--ckpt_path`` is data: read it safely (one line if it is missing,
        empty, damaged or more than weights), refuse one of another model class than
        the config's (compared as names, nothing it names is imported; LightningCLI
        would import its ``_class_path`` and build that class under the config's run
        name), and restore its plain hyperparameters into the config's class."""
        sub = self.config.get("subcommand")
        config = self.config.get(sub) if sub else None
        ckpt_path = config.get("ckpt_path") if config else None
        if not check_ckpt_path(ckpt_path):
            return
        ckpt = load_checkpoint(ckpt_path)
        model = config.get("model")
        check_checkpoint(ckpt_path, ckpt, model)
        restored = checkpoint_init_args(ckpt, getattr(model, "init_args", None))
        if restored:
            update = {sub: {"model": {"class_path": model.class_path, "init_args": restored}}}
            self.config = self.parser.parse_object(update, self.config)

    def before_instantiate_classes(self) -> None:
        import torch

        config = self.config.get(str(self.subcommand), self.config)
        torch.set_num_threads(choose_threads(config.get("threads", "auto")))
        _refuse_explicit_input_dim(config.get("model"))
        if "weights_only" in config and config["weights_only"] is None:
            config["weights_only"] = True  # a checkpoint cannot run code when loaded

    def instantiate_classes(self) -> None:
        """Build the classes; Lightning's refusals of trainer options (``max_steps:
        -5``) become one line."""
        from lightning.fabric.utilities.exceptions import MisconfigurationException

        try:
            super().instantiate_classes()
        except MisconfigurationException as err:
            raise CLIError(f"trainer: {str(err).strip().splitlines()[0]}") from None

    def after_instantiate_classes(self) -> None:
        """Checkpoints are saved atomically (a failed save never replaces a good
        ``last.ckpt``); ``predict``'s file of starts is checked before any data."""
        from hnn_pl.callbacks import RolloutWriter
        from hnn_pl.safe_io import atomic_checkpoint_io

        super().after_instantiate_classes()
        if getattr(self, "trainer", None) is None:
            return
        self.trainer.strategy.checkpoint_io = atomic_checkpoint_io()
        for callback in self.trainer.callbacks:
            if isinstance(callback, RolloutWriter) and callback.starts is not None:
                check_starts(callback.starts, _start_width(self.model, self.datamodule))


def _start_width(model: Any, datamodule: Any) -> int:
    """The width of a start ``predict`` integrates from: a pixel model's frame pair
    (``input_dim``), else the data's ``state_dim``."""
    from hnn_pl.rollouts import is_pixel_model

    if is_pixel_model(model):
        return int(model.hparams["input_dim"])
    return int(datamodule.state_dim)


def _refuse_explicit_input_dim(model: Any) -> None:
    """The link from ``data.state_dim`` silently replaces a given ``input_dim``: refuse
    one that differs from the class's default (the only way it can be told apart)."""
    import inspect

    class_path = getattr(model, "class_path", None)
    given = getattr(getattr(model, "init_args", None), "input_dim", None)
    if class_path is None or given is None:
        return
    cls = loaded_class(class_path)  # the config's class: imported when it was parsed
    if cls is None:
        return
    params = inspect.signature(cls).parameters
    if "input_dim" in params and given != params["input_dim"].default:
        raise ValueError(
            f"model.init_args.input_dim = {given}: the model's input size is taken from the "
            "data (its state_dim); remove the option"
        )


def cli_main(args: ArgsType = None, run: bool = True, save_config: bool = True) -> HNNCLI:
    """Run the CLI on ``args`` (``sys.argv[1:]`` when ``None``); returns the CLI object.
    Bad input raises :class:`~hnn_pl.cli_errors.CLIError` (or another one-line
    ``ValueError``) before any data, directory or checkpoint is written.
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
