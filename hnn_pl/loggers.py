"""A TensorBoard logger whose HParams tab shows every hyperparameter of a run and its
rollout metrics, not ``hp_metric = -1``; where a run's files are
(``save_dir/name/version_N/checkpoints/last.ckpt``: :func:`resolve_checkpoint`,
:func:`run_directory`), and a refused run's taken back (:class:`RefusedRun`); Lightning's
lines that tell a run nothing, off (:func:`quiet_lines`)."""

from __future__ import annotations

import logging
import os
import re
import warnings
from pathlib import Path
from typing import Any

from lightning.fabric.utilities.logger import _convert_params, _flatten_dict
from lightning.pytorch.loggers import TensorBoardLogger as _TensorBoardLogger
from lightning.pytorch.utilities.rank_zero import rank_zero_only

#: the starts of Lightning's info lines (``lightning.pytorch.utilities.rank_zero``) that
#: tell a run of this project nothing (and would stand before a command's refusal): its
#: tips advertising cloud services, the device banner (the runs are on the CPU) and the
#: checkpoint it restores (the one ``--ckpt_path`` named, or its run's)
_NOISE = (
    "💡 Tip: For seamless cloud ",
    "GPU available: ",
    "TPU available: ",
    "HPU available: ",
    "Restoring states from the checkpoint path at ",
    "Restored all states from the checkpoint at ",
    "Loaded model weights from the checkpoint at ",
)


def _not_noise(record: logging.LogRecord) -> bool:
    return not record.getMessage().startswith(_NOISE)


def quiet_lines() -> None:
    """Drop Lightning's info lines in :data:`_NOISE` (a filter on its ``rank_zero``
    logger) and its pytree ``LeafSpec`` FutureWarning (by its message)."""
    logging.getLogger("lightning.pytorch.utilities.rank_zero").addFilter(_not_noise)
    warnings.filterwarnings("ignore", message=".*LeafSpec.*", category=FutureWarning)


class TensorBoardLogger(_TensorBoardLogger):
    """Lightning's ``TensorBoardLogger`` writing *one* hparams summary per run.

    Lightning writes an hparams summary at every ``log_hyperparams`` call, and
    TensorBoard's HParams tab reads only the first: the rollout callback's (model
    class, system, protocol) hid the model's and the data's (``lr``, ``hidden_dim``,
    ``schedule``, ``noise_std``, …). This logger collects every call's params and
    writes a single summary holding all of them when the run first saves or logs a
    metric (Lightning logs all hyperparameters before either). The summary registers
    the metric *tags* ``hp_metrics`` (default ``rollout/energy_mse``): TensorBoard
    reads their values from the scalars the rollout callback logs, and no placeholder
    ``hp_metric`` is written. A run that already has its summary (``test`` or
    ``predict`` logging into the run they evaluate) gets no second one. Runs are told
    apart by ``name`` (e.g. ``spring_hnn``): logs go to ``save_dir/name/version_N``.
    ``metrics_logged`` says whether the run has logged a metric yet (a run refused
    before that has nothing of its own to keep: :class:`RefusedRun`). LightningCLI's
    ``_instantiator`` (how it rebuilds the class from a checkpoint, not an option) is kept
    out of the logged hyperparameters.

    Args:
        save_dir, name, version: as Lightning's logger.
        hp_metrics: the scalar tags shown as metrics in the HParams tab.
        **kwargs: passed on (``default_hp_metric`` is forced off).
    """

    def __init__(
        self,
        save_dir: str = "lightning_logs",
        name: str | None = "default",
        version: int | str | None = None,
        hp_metrics: tuple[str, ...] = ("rollout/energy_mse",),
        **kwargs: Any,
    ) -> None:
        kwargs["default_hp_metric"] = False
        super().__init__(save_dir, name=name, version=version, **kwargs)
        self.hp_metrics = tuple(hp_metrics)
        self._hparams_summary_done = False
        self.metrics_logged = False

    def _write_hparams_summary(self) -> None:
        if self._hparams_summary_done or not self.hparams:
            return
        self._hparams_summary_done = True
        if Path(self.log_dir, self.NAME_HPARAMS_FILE).is_file() or not self.hp_metrics:
            return
        from torch.utils.tensorboard.summary import hparams

        flat = self._sanitize_params(_flatten_dict(_convert_params(self.hparams)))
        writer = self.experiment.file_writer
        for summary in hparams(flat, dict.fromkeys(self.hp_metrics, 0.0)):
            writer.add_summary(summary)

    @rank_zero_only
    def log_hyperparams(self, params: Any, *args: Any, **kwargs: Any) -> None:
        if isinstance(params, dict) and "_instantiator" in params:
            params = {k: v for k, v in params.items() if k != "_instantiator"}
        super().log_hyperparams(params, *args, **kwargs)

    @rank_zero_only
    def log_metrics(self, metrics: dict[str, Any], step: int | None = None) -> None:
        self.metrics_logged = True
        self._write_hparams_summary()
        super().log_metrics(metrics, step)

    @rank_zero_only
    def save(self) -> None:
        self._write_hparams_summary()
        super().save()


def run_name(*class_paths: str | None) -> str:
    """A run's name from its classes' paths (the system or data, then the model): their
    names in snake case, e.g. ``mass_spring_hnn``."""
    names = [p.rsplit(".", 1)[-1] for p in class_paths if p]
    snake = [re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", n).lower() for n in names]
    return "_".join(snake) or "default"


#: ``ckpt_path`` values Lightning resolves itself (not files)
SPECIAL_CKPT_PATHS = ("last", "best", "hpc")


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


def run_directory(ckpt_path: str | None) -> Path | None:
    """``…/name/version_N`` of a checkpoint in ``…/name/version_N/checkpoints/``."""
    if not ckpt_path or "://" in ckpt_path or not Path(ckpt_path).is_file():
        return None
    parent = Path(ckpt_path).resolve().parent
    return parent.parent if parent.name == "checkpoints" else None


class RefusedRun:
    """What a run refused after parsing leaves in its log directory, taken back.

    Lightning makes the run's directory when the run starts (``…/name/version_N``:
    making it reserves the version against a concurrent run) and writes the run's
    ``config*.yaml`` (LightningCLI), ``hparams.yaml`` and an event file into it before
    the data, the model and a resumed checkpoint are checked and the first batch
    runs. A run stopped by bad input (the commands' ``user_error``)
    before it logged a metric or wrote any other file has nothing of its own:
    :meth:`discard` removes those files (event files: this process's) and the
    directories this run made. A run with metrics, a checkpoint or any other new file
    is kept whole. Only the project's :class:`~hnn_pl.loggers.TensorBoardLogger` is
    looked after.
    """

    def __init__(self, trainer: Any, config_file: str) -> None:
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
