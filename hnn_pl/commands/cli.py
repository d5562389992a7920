"""``python -m hnn_pl {fit,validate,test,predict} --config X.yaml`` (LightningCLI).

Classes go by short names (``--model HNN --data.system MassSpring``: this module
imports every model, data module and system) or import paths. Every run starts from
:data:`TRAINER_DEFAULTS`; ``--ckpt_path`` takes a checkpoint, a run or a run name's
directory, and ``validate``, ``test``, ``predict`` log into the run they evaluate. The
optimiser is the model's recipe: ``--optimizer``/``--lr_scheduler`` are refused.
``fit``, ``test`` and ``predict`` end with a summary (:func:`print_summary`).
"""

from __future__ import annotations

import json
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
from hnn_pl.commands.cli_errors import (
    CLIError,
    check_ckpt_path,
    check_starts,
    check_threads,
    check_trainer_numbers,
    given_model_options,
    one_line,
    program_name,
    user_error,
)
from hnn_pl.commands.config_paths import resolve_config_args
from hnn_pl.loggers import (
    SPECIAL_CKPT_PATHS,
    RefusedRun,
    quiet_lines,
    resolve_checkpoint,
    run_directory,
    run_name,
)
from hnn_pl.safe_io import (
    check_model_class,
    checkpoint_init_args,
    idle_cores,
    load_checkpoint,
    loaded_class,
    refuse_changed_options,
)

#: the packages whose classes the CLI knows by their short names
REGISTERED = (models, data, systems)

#: the trainer settings every run shares (the configs give what differs)
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

#: a run that records nothing and skips validation (reproduce, stress, benchmarks)
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


#: LightningCLI's optimiser options: they would replace the recipe's unrecorded
_NOT_RECIPE = ("--optimizer", "--lr_scheduler")


def quiet_lightning() -> None:
    """Lightning's lines that tell a run nothing off (:func:`hnn_pl.loggers.quiet_lines`),
    and the CLI's warnings by their message (``args`` beside ``sys.argv``: we pass the
    resolved argv; ``dirpath``) and jsonargparse's deprecations by its switch."""
    quiet_lines()
    warnings.filterwarnings("ignore", message=".*LightningCLI's args parameter is intended.*")
    warnings.filterwarnings("ignore", message=".*The dirpath has changed.*")
    os.environ.setdefault("JSONARGPARSE_DEPRECATION_WARNINGS", "off")


class HNNArgumentParser(LightningArgumentParser):
    """Usage lines name the program as run (``hnn-pl`` or ``python -m hnn_pl``), also in
    the parsers ``--model.help X`` builds."""

    def __init__(self, *args, **kwargs) -> None:
        if not args:
            kwargs.setdefault("prog", program_name())
        super().__init__(*args, **kwargs)

    def error(self, message: str, ex: Exception | None = None):
        """A parse error is one line (:func:`~hnn_pl.commands.cli_errors.one_line`)."""
        if not self.exit_on_error:
            return super().error(message, ex)
        raise CLIError(one_line(message, self)) from None


class HNNCLI(LightningCLI):
    """LightningCLI that links the DataModule's ``state_dim`` to the model's ``input_dim``
    and sets torch's threads (``--threads N``, or ``auto``: the idle cores). A refusal
    is the only line a command prints, and a run refused before it logged anything
    takes back its files (:class:`~hnn_pl.loggers.RefusedRun`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        argv = kwargs.get("args")
        first = str(argv[0]) if isinstance(argv, (list, tuple)) and argv else None
        self._named_subcommand = first if first in LightningCLI.subcommands() else None
        super().__init__(*args, **kwargs)

    def subcommands(self) -> dict[str, set[str]]:  # type: ignore[override]
        """LightningCLI's subcommands, or only the one the command line starts with: each
        subcommand's parser reads the trainer's, model's and data's signatures again, and
        three unused ones were a third of a command's parsing (``--help`` alone, or a
        command line starting with anything else, still gets all four)."""
        every = LightningCLI.subcommands()
        named = self._named_subcommand
        return every if named is None else {named: every[named]}

    def add_arguments_to_parser(self, parser) -> None:
        parser.link_arguments("data.state_dim", "model.init_args.input_dim", apply_on="instantiate")
        parser.add_argument(
            "--threads",
            type=int | str,
            default="auto",
            help="torch threads: a number, or auto (cores not busy with other processes)",
        )

    def parse_arguments(self, parser: LightningArgumentParser, args: ArgsType) -> None:
        """Parse, keeping the command line for :meth:`_parse_ckpt_path`."""
        self._argv = [str(a) for a in args] if isinstance(args, (list, tuple)) else []
        super().parse_arguments(parser, args)

    def _parse_ckpt_path(self) -> None:
        """A ``--ckpt_path`` is data (:mod:`hnn_pl.safe_io`): read safely, refused if
        of another model class than the config's (compared as names: nothing it names
        is imported) or if options given on the command line differ from its own; its
        other plain hyperparameters are restored into the config's class."""
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
        if getattr(init_args, "objective", None) == "auto":  # as the model resolves it
            window = getattr(getattr(config.get("data"), "init_args", None), "window", None)
            init_args.objective = "derivative" if window is None else "trajectory"
        given = given_model_options(getattr(self, "_argv", []))
        refuse_changed_options(ckpt, init_args, given, f"checkpoint {ckpt_path}")
        restored = checkpoint_init_args(ckpt, init_args, given)
        if restored:
            update = {sub: {"model": {"class_path": model.class_path, "init_args": restored}}}
            self.config = self.parser.parse_object(update, self.config)

    def _set_seed(self) -> None:
        """LightningCLI's seeding (``seed_everything``: a seed, ``true``: Lightning's,
        ``false``: none) without its lines; a seed beyond numpy's range is refused."""
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
        threads = check_threads(config.get("threads", "auto"))
        torch.set_num_threads(idle_cores() if threads is None else threads)
        check_trainer_numbers(config.get("trainer", {}))
        _refuse_explicit_input_dim(config.get("model"))
        if "weights_only" in config and config["weights_only"] is None:
            config["weights_only"] = True  # a checkpoint cannot run code when loaded
        logger = config.get("trainer", {}).get("logger")
        init_args = getattr(logger, "init_args", None)
        if init_args is None or not {"save_dir", "name", "version"} <= set(vars(init_args)):
            return
        if init_args.name is None:
            data, model = config.get("data"), config.get("model")
            system = getattr(getattr(data, "init_args", None), "system", None)
            init_args.name = run_name(
                *(getattr(x, "class_path", None) for x in (system or data, model))
            )
        run = run_directory(config.get("ckpt_path"))
        if self.subcommand != "fit" and run is not None:
            init_args.save_dir, init_args.name = str(run.parent.parent), run.parent.name
            init_args.version = run.name

    def instantiate_trainer(self, **kwargs: Any):
        """The trainer, with a :class:`~hnn_pl.callbacks.FinalCheckpoint` and a
        :class:`~hnn_pl.callbacks.StepProgressBar` (first: it closes before the final
        rollout) unless they are off or the config names its own."""
        from lightning.pytorch.callbacks import ModelCheckpoint, ProgressBar

        from hnn_pl.callbacks import FinalCheckpoint, StepProgressBar

        config = self._get(self.config_init, "trainer", default={})
        callbacks = list(kwargs.get("callbacks", config.get("callbacks")) or [])
        if config.get("enable_checkpointing") is not False:
            if not any(isinstance(c, ModelCheckpoint) for c in callbacks):
                callbacks.append(FinalCheckpoint())
        if config.get("enable_progress_bar") is not False:
            if not any(isinstance(c, ProgressBar) for c in callbacks):
                callbacks.insert(0, StepProgressBar())
        kwargs["callbacks"] = callbacks
        return super().instantiate_trainer(**kwargs)

    def instantiate_classes(self) -> None:
        """Build the classes; Lightning's refusals of trainer options are one line."""
        from lightning.fabric.utilities.exceptions import MisconfigurationException

        try:
            super().instantiate_classes()
        except MisconfigurationException as err:
            raise CLIError(f"trainer: {str(err).strip().splitlines()[0]}") from None

    def after_instantiate_classes(self) -> None:
        """Checkpoints are saved atomically; ``predict``'s starts, the data and the
        checkpoint (the model's ``check_run``) are checked before anything is written."""
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

    def after_fit(self) -> None:
        """Printed last: the run, its checkpoint, the rollouts written and the metrics of
        the last rollout (``test``, or without a rollout: what the run logged)."""
        from hnn_pl.callbacks import RolloutCallback, RolloutWriter

        trainer, fit = self.trainer, self.subcommand == "fit"
        title = {"fit": "final rollout", "test": "test"}.get(str(self.subcommand), "rollout")
        callbacks = [c for c in trainer.callbacks if isinstance(c, RolloutCallback | RolloutWriter)]
        metrics = next((c.metrics for c in callbacks if c.metrics), {}) if title != "test" else {}
        if not metrics:
            title = "test" if title == "test" else "logged"
            metrics = {k.removeprefix("rollout/"): v for k, v in trainer.callback_metrics.items()}
        paths = [c.path for c in callbacks if isinstance(c, RolloutWriter) and c.path]
        saved = getattr(trainer.checkpoint_callback, "last_model_path", None)
        checkpoint = saved if fit else trainer.ckpt_path
        if trainer.is_global_zero:
            run = trainer.log_dir if trainer.logger is not None else None
            files = {"rollouts": paths[0]} if paths else None
            print_summary(run, checkpoint, metrics, title, files)

    after_test = after_predict = after_fit

    def _run_subcommand(self, subcommand: str) -> None:
        """Run ``subcommand``; a run bad input stops before it logged anything leaves no
        files (:class:`~hnn_pl.loggers.RefusedRun`), and the error goes on."""
        config_file = self.save_config_kwargs.get("config_filename", "config.yaml")
        run = RefusedRun(self.trainer, config_file)
        try:
            super()._run_subcommand(subcommand)
        except Exception as err:
            if user_error(err) is not None:
                run.discard()
            raise


def print_summary(run: Any, checkpoint: Any, metrics: dict, title: str, files: Any = None) -> None:
    """How a command went, as its last lines: the run directory, the checkpoint, other
    ``files`` (name → path) and ``metrics`` as a table under ``title`` (the error floors
    of the true system's own rollouts aside: they are in the run's logs)."""
    rows = {"run": run or "(not logged)", "checkpoint": checkpoint or "(none)", **(files or {})}
    lines = ["", *(f"{k:<11} {v}" for k, v in rows.items())]
    metrics = {k: v for k, v in metrics.items() if not k.startswith("floor_")}
    if metrics:
        width = max(len("metric"), *map(len, metrics))
        lines += [f"{title}:", f"  {'metric':<{width}}  value"]
        lines += [f"  {k:<{width}}  {float(v):.4g}" for k, v in metrics.items()]
    print("\n".join(lines), flush=True)


def _start_width(model: Any, datamodule: Any) -> int:
    """The width of a ``predict`` start: a pixel model's frame pair, else a state."""
    from hnn_pl.evaluation import view_of

    return view_of(model).start_width(datamodule)


def _refuse_explicit_input_dim(model: Any) -> None:
    """Refuse an ``input_dim`` other than the class's default: the link from
    ``data.state_dim`` would silently replace it."""
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
    Bad input raises a one-line ``ValueError`` before anything is written.
    ``save_config=False``: no ``config.yaml`` beside the run."""
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
    """``config`` plus ``options`` as a quiet run (:data:`QUIET_TRAINER`), not started:
    the experiments' :class:`~hnn_pl.experiments.collect.Build`."""
    args = ["--config", config, *quiet_args(), *options]
    return cli_main(args, run=False, save_config=save_config)
