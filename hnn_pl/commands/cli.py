"""``python -m hnn_pl {fit,validate,test,predict} --config X.yaml`` (LightningCLI).

Classes are given by their short names (``--model HNN --data SimulatedData
--data.system MassSpring``, ``--model.help HNN``) or by import path: jsonargparse
resolves a short name among the subclasses imported when the parser is built, so this
module imports every model, data module and system (only the full commands load this
module; ``python -m hnn_pl --help`` does not).

Every run starts from :data:`TRAINER_DEFAULTS` (a config's trainer block overrides
each key); a config may extend another (``base:``, see :mod:`hnn_pl.commands.config_paths`).
``--ckpt_path`` takes a checkpoint, a run directory (``…/version_N``) or a run name's
directory (``lightning_logs/spring_fast_hnn``: its latest run), see
:func:`resolve_checkpoint`; ``validate``, ``test`` and ``predict`` log into the run
they evaluate. The optimiser and its schedule are the model's recipe
(``--model.init_args.optimizer``, ``lr``, ``schedule``): LightningCLI's
``--optimizer``/``--lr_scheduler`` are refused, not silently overridden.
"""

from __future__ import annotations

import json
import logging
import os
import re
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
from hnn_pl.commands.cli_errors import (
    SPECIAL_CKPT_PATHS,
    CLIError,
    check_ckpt_path,
    check_starts,
    check_threads,
    check_trainer_numbers,
    checkpoint_init_args,
    given_model_options,
    one_line,
    program_name,
    refuse_changed_options,
    user_error,
)
from hnn_pl.commands.config_paths import resolve_config_args
from hnn_pl.safe_io import check_model_class, load_checkpoint, loaded_class

#: the packages whose classes the CLI knows by their short names
REGISTERED = (models, data, systems)

#: the trainer settings every run shares (the configs give only what differs): the
#: paper's 2000 steps on one CPU, a log line per step, validation every epoch, logged
#: under the config's run name, else a name from the classes (``--model HNN
#: --data.system MassSpring``: ``lightning_logs/mass_spring_hnn``)
TRAINER_DEFAULTS: dict[str, Any] = {
    "max_steps": 2000,
    "max_epochs": -1,
    "accelerator": "cpu",
    "devices": 1,
    "inference_mode": False,
    "log_every_n_steps": 1,
    "check_val_every_n_epoch": 1,
    "enable_model_summary": False,
    "logger": {
        "class_path": "hnn_pl.loggers.TensorBoardLogger",
        "init_args": {"save_dir": "lightning_logs", "name": None},
    },
}

#: a run that records nothing and skips validation (reproduce, stress, benchmarks,
#: tests, examples): no logger, checkpoints, progress bar, summary or callbacks
QUIET_TRAINER: dict[str, Any] = {
    "logger": False,
    "enable_checkpointing": False,
    "enable_progress_bar": False,
    "enable_model_summary": False,
    "callbacks": [],
    "limit_val_batches": 0,
}


def quiet_args() -> list[str]:
    """:data:`QUIET_TRAINER` as ``--trainer.KEY=VALUE`` options of :func:`cli_main`."""
    return [f"--trainer.{k}={json.dumps(v)}" for k, v in QUIET_TRAINER.items()]


#: LightningCLI's optimiser options, which would replace the recipe's optimiser while
#: the hparams still record the recipe's
_NOT_RECIPE = ("--optimizer", "--lr_scheduler")


#: Lightning's info lines (``lightning.pytorch.utilities.rank_zero``) that tell a run of
#: this project nothing and would stand before a refusal's one line: its advertising
#: tip, the device banner (the runs are on the CPU, :data:`TRAINER_DEFAULTS`) and the
#: checkpoint it restores (the one ``--ckpt_path`` named, or :func:`resolve_checkpoint`'s)
_NOISE = (
    "💡",
    "LitLogger",
    "GPU available: ",
    "TPU available: ",
    "HPU available: ",
    "Restoring states from the checkpoint path at ",
    "Restored all states from the checkpoint at ",
    "Loaded model weights from the checkpoint at ",
)


class _DropNoise(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        return not any(part in message for part in _NOISE)


_DROP_NOISE = _DropNoise()


def quiet_lightning() -> None:
    """Drop Lightning's lines in :data:`_NOISE`, its pytree ``LeafSpec`` FutureWarning,
    its warning about ``args`` beside ``sys.argv`` (we pass the resolved argv) and the
    jsonargparse 4.49 deprecations that LightningCLI 2.6 triggers (not ours to fix).
    The seed is set without a line (:meth:`HNNCLI._set_seed`)."""
    logging.getLogger("lightning.pytorch.utilities.rank_zero").addFilter(_DROP_NOISE)
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
    and sets torch's thread count (``--threads N|auto``, see :func:`choose_threads`).

    A refusal is the only line a command prints: the seed is set without Lightning's
    line (:meth:`_set_seed`), and a run refused before it logged anything takes back
    the files it made (:class:`RefusedRun`)."""

    def add_arguments_to_parser(self, parser) -> None:
        parser.link_arguments("data.state_dim", "model.init_args.input_dim", apply_on="instantiate")
        parser.add_argument(
            "--threads",
            type=int | str,
            default="auto",
            help="torch threads: a number, or auto (cores not busy with other processes)",
        )

    def parse_arguments(self, parser: LightningArgumentParser, args: ArgsType) -> None:
        """Parse, and keep the command line: options given on it are compared with a
        checkpoint's (:meth:`_parse_ckpt_path`)."""
        self._argv = [str(a) for a in args] if isinstance(args, (list, tuple)) else []
        super().parse_arguments(parser, args)

    def _parse_ckpt_path(self) -> None:
        """A ``--ckpt_path`` is data: read it safely (one line if it is missing,
        empty, damaged, more than weights or not finite), refuse one of another model
        class than the config's (compared as names, nothing it names is imported;
        LightningCLI would import its ``_class_path`` and build that class under the
        config's run name), refuse model options given on the command line that differ
        from its own (:func:`~hnn_pl.commands.cli_errors.refuse_changed_options`), and
        restore its other plain hyperparameters into the config's class."""
        self._checkpoint = None
        sub = self.config.get("subcommand")
        config = self.config.get(sub) if sub else None
        ckpt_path = config.get("ckpt_path") if config else None
        if ckpt_path and ckpt_path not in SPECIAL_CKPT_PATHS:
            config["ckpt_path"] = ckpt_path = resolve_checkpoint(ckpt_path)
        if not check_ckpt_path(ckpt_path):
            return
        ckpt = self._checkpoint = load_checkpoint(ckpt_path)
        model = config.get("model")
        if getattr(model, "class_path", None):
            check_model_class(ckpt, model.class_path, f"checkpoint {ckpt_path}")
        init_args = getattr(model, "init_args", None)
        given = given_model_options(getattr(self, "_argv", []))
        refuse_changed_options(ckpt, init_args, given, f"checkpoint {ckpt_path}")
        restored = checkpoint_init_args(ckpt, init_args, given)
        if restored:
            update = {sub: {"model": {"class_path": model.class_path, "init_args": restored}}}
            self.config = self.parser.parse_object(update, self.config)

    def _set_seed(self) -> None:
        """LightningCLI's seeding (``seed_everything``: a seed; ``true``: Lightning's,
        ``$PL_GLOBAL_SEED`` else 0; ``false``: none), without its "Seed set to N" line
        and "No seed found" warning; a seed beyond numpy's range is refused naming the
        option."""
        from lightning.fabric.utilities.seed import max_seed_value, seed_everything

        config = self.config.get(str(self.subcommand), self.config)
        seed = config.get("seed_everything")
        if seed is False:
            return
        if seed is not True and not 0 <= seed <= max_seed_value:
            raise CLIError(
                f"seed_everything must be true, false or an integer in [0, {max_seed_value}], "
                f"got {seed}"
            )
        seed = None if seed is True else seed
        config["seed_everything"] = seed_everything(seed, workers=True, verbose=False)

    def before_instantiate_classes(self) -> None:
        import torch

        config = self.config.get(str(self.subcommand), self.config)
        torch.set_num_threads(choose_threads(config.get("threads", "auto")))
        check_trainer_numbers(config.get("trainer", {}))
        _refuse_explicit_input_dim(config.get("model"))
        if "weights_only" in config and config["weights_only"] is None:
            config["weights_only"] = True  # a checkpoint cannot run code when loaded
        logger = config.get("trainer", {}).get("logger")
        init_args = getattr(logger, "init_args", None)
        if init_args is None or not {"save_dir", "name", "version"} <= set(vars(init_args)):
            return
        if init_args.name is None:
            init_args.name = _run_name(config.get("model"), config.get("data"))
        run = _run_directory(config.get("ckpt_path"))
        if self.subcommand != "fit" and run is not None:
            init_args.save_dir, init_args.name = str(run.parent.parent), run.parent.name
            init_args.version = run.name

    def instantiate_trainer(self, **kwargs: Any):
        """The trainer, with a :class:`~hnn_pl.callbacks.FinalCheckpoint` unless
        checkpointing is off or the config names a checkpoint callback."""
        from lightning.pytorch.callbacks import ModelCheckpoint

        from hnn_pl.callbacks import FinalCheckpoint

        config = self._get(self.config_init, "trainer", default={})
        callbacks = list(kwargs.get("callbacks", config.get("callbacks")) or [])
        wanted = config.get("enable_checkpointing") is not False
        if wanted and not any(isinstance(c, ModelCheckpoint) for c in callbacks):
            kwargs["callbacks"] = [*callbacks, FinalCheckpoint()]
        return super().instantiate_trainer(**kwargs)

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
        ``last.ckpt``); ``predict``'s file of starts is checked before any data; the
        model's checks of the data and of the checkpoint (``check_run``) run before any
        run directory is written."""
        from hnn_pl.callbacks import RolloutWriter
        from hnn_pl.safe_io import atomic_checkpoint_io

        super().after_instantiate_classes()
        if getattr(self, "trainer", None) is None:
            return
        self.trainer.strategy.checkpoint_io = atomic_checkpoint_io()
        for callback in self.trainer.callbacks:
            if isinstance(callback, RolloutWriter) and callback.starts is not None:
                check_starts(callback.starts, _start_width(self.model, self.datamodule))
        check_run = getattr(self.model, "check_run", None)  # the model's refusals, before a run
        if check_run is not None and self.subcommand is not None:
            path = self.config.get(self.subcommand).get("ckpt_path")
            check_run(self.datamodule, self.subcommand, self._checkpoint, f"checkpoint {path}")

    def _run_subcommand(self, subcommand: str) -> None:
        """Run ``subcommand``; if bad input stops it before it logged anything (a data
        or model check at setup, a checkpoint that does not fit, the first batch),
        :class:`RefusedRun` takes back the run's files, and the error goes on."""
        config_file = self.save_config_kwargs.get("config_filename", "config.yaml")
        run = RefusedRun(self.trainer, config_file)
        try:
            super()._run_subcommand(subcommand)
        except Exception as err:
            if user_error(err) is not None:
                run.discard()
            raise


class RefusedRun:
    """What a run refused after parsing leaves in its log directory, taken back.

    Lightning makes the run's directory when the run starts (``…/name/version_N``:
    making it reserves the version against a concurrent run) and writes the run's
    ``config*.yaml`` (LightningCLI), ``hparams.yaml`` and an event file into it before
    the data, the model and a resumed checkpoint are checked and the first batch
    runs. A run stopped by bad input (:func:`~hnn_pl.commands.cli_errors.user_error`)
    before it logged a metric or wrote any other file has nothing of its own:
    :meth:`discard` removes those files (event files: this process's) and the
    directories this run made. A run with metrics, a checkpoint or any other new file
    is kept whole. Only the project's :class:`~hnn_pl.loggers.TensorBoardLogger` is
    looked after.
    """

    def __init__(self, trainer: Any, config_file: str) -> None:
        from hnn_pl.loggers import TensorBoardLogger

        logger = getattr(trainer, "logger", None)
        self.logger = logger if isinstance(logger, TensorBoardLogger) else None
        if self.logger is None or not trainer.is_global_zero:
            self.logger = None
            return
        self.run = Path(self.logger.log_dir)
        self.made_dirs = [
            d
            for d in (Path(self.logger.save_dir), Path(self.logger.root_dir), self.run)
            if not d.exists()
        ]
        self.names = (config_file, self.logger.NAME_HPARAMS_FILE)
        self.before = self._files()

    def _files(self) -> set[Path]:
        return {p for p in self.run.rglob("*") if p.is_file()} if self.run.is_dir() else set()

    def _bookkeeping(self, path: Path) -> bool:
        """Whether ``path`` is the run's config, its hparams file or an event file of
        this process (``events.out.tfevents.<time>.<host>.<pid>.<n>``)."""
        if path.parent != self.run:
            return False
        event = path.name.startswith("events.out.tfevents.") and f".{os.getpid()}." in path.name
        return event or path.name in self.names

    def discard(self) -> None:
        if self.logger is None or self.logger.metrics_logged:
            return
        self.logger.finalize("failed")  # closes the event file
        new = self._files() - self.before
        if not all(self._bookkeeping(path) for path in new):
            return
        for path in new:
            path.unlink()
        for directory in reversed(self.made_dirs):
            try:
                directory.rmdir()
            except OSError:  # not empty: it holds what another run wrote meanwhile
                return


def resolve_checkpoint(path: str) -> str:
    """The checkpoint a ``--ckpt_path`` names: a file as given; a run directory
    (``…/version_N``) or its ``checkpoints/``: its ``last.ckpt``; a directory of runs
    (``lightning_logs/spring_fast_hnn``): the ``last.ckpt`` of its highest
    ``version_N``. URLs and Lightning's ``last``/``best``/``hpc`` pass unchanged.

    Raises:
        FileNotFoundError: nothing there, naming what was looked for.
    """
    if "://" in path or path in SPECIAL_CKPT_PATHS or Path(path).is_file():
        return path
    p = Path(path)
    if not p.is_dir():
        raise FileNotFoundError(f"checkpoint {path}: no such file or run directory")
    for last in (p / "last.ckpt", p / "checkpoints" / "last.ckpt"):
        if last.is_file():
            return str(last)
    runs = [d for d in p.glob("version_*") if (d / "checkpoints" / "last.ckpt").is_file()]
    if not runs:
        raise FileNotFoundError(
            f"checkpoint {path}: a directory without checkpoints/last.ckpt or runs "
            "version_N/ holding one"
        )
    number = lambda d: int(d.name[8:]) if d.name[8:].isdigit() else -1  # noqa: E731
    latest = max(runs, key=lambda d: (number(d), d.stat().st_mtime))
    return str(latest / "checkpoints" / "last.ckpt")


def _run_directory(ckpt_path: str | None) -> Path | None:
    """``…/name/version_N`` of a checkpoint in ``…/name/version_N/checkpoints/``."""
    if not ckpt_path or "://" in ckpt_path or not Path(ckpt_path).is_file():
        return None
    parent = Path(ckpt_path).resolve().parent
    return parent.parent if parent.name == "checkpoints" else None


def _snake(name: str) -> str:
    return re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", name).lower()


def _run_name(model: Any, data: Any) -> str:
    """``<system or data class>_<model class>`` in snake case, e.g. ``mass_spring_hnn``."""
    system = getattr(getattr(data, "init_args", None), "system", None)
    named = [getattr(x, "class_path", None) for x in (system or data, model)]
    return "_".join(_snake(p.rsplit(".", 1)[-1]) for p in named if p) or "default"


def _start_width(model: Any, datamodule: Any) -> int:
    """The width of a start ``predict`` integrates from: a pixel model's frame pair
    (``input_dim``), else the data's ``state_dim``."""
    from hnn_pl.evaluation import view_of

    return view_of(model).start_width(datamodule)


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
    Bad input raises :class:`~hnn_pl.commands.cli_errors.CLIError` (or another one-line
    ``ValueError``) before any data, directory or checkpoint is written.
    ``save_config=False``: no ``config.yaml`` beside the run (programmatic fits)."""
    import sys

    quiet_lightning()
    args = resolve_config_args(sys.argv[1:] if args is None else list(args))
    for arg in args:
        option = arg.split("=", 1)[0]
        if option.split(".", 1)[0] in _NOT_RECIPE:
            raise ValueError(
                f"{option}: the optimiser and its schedule are the model's recipe; set "
                "--model.init_args.optimizer (adam, adamw, lbfgs), --model.init_args.lr, "
                "--model.init_args.schedule (constant, cosine, onecycle)"
            )
    evaluates = args[:1] if args[:1] in (["validate"], ["test"], ["predict"]) else []
    config_file = f"config_{evaluates[0]}.yaml" if evaluates else "config.yaml"
    return HNNCLI(
        LightningModule,
        LightningDataModule,
        subclass_mode_model=True,
        subclass_mode_data=True,
        args=args,
        run=run,
        save_config_kwargs={"overwrite": True, "config_filename": config_file},
        save_config_callback=SaveConfigCallback if save_config else None,
        parser_class=HNNArgumentParser,
        trainer_defaults=TRAINER_DEFAULTS,
        auto_configure_optimizers=False,
    )


def quiet_run(
    config: str, options: list[str] | tuple[str, ...] = (), save_config: bool = False
) -> HNNCLI:
    """``config`` plus ``options`` built by :func:`cli_main` as a quiet run
    (:data:`QUIET_TRAINER`), not started: how the experiments build their runs
    (:class:`hnn_pl.experiments.collect.Build`; they never import this package)."""
    args = ["--config", config, *quiet_args(), *options]
    return cli_main(args, run=False, save_config=save_config)
