"""A TensorBoard logger whose HParams tab shows every hyperparameter of a run and its
rollout metrics, not ``hp_metric = -1``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lightning.fabric.utilities.logger import _convert_params, _flatten_dict
from lightning.pytorch.loggers import TensorBoardLogger as _TensorBoardLogger
from lightning.pytorch.utilities.rank_zero import rank_zero_only


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
    before that has nothing of its own to keep: :class:`hnn_pl.commands.cli.RefusedRun`).

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
    def log_metrics(self, metrics: dict[str, Any], step: int | None = None) -> None:
        self.metrics_logged = True
        self._write_hparams_summary()
        super().log_metrics(metrics, step)

    @rank_zero_only
    def save(self) -> None:
        self._write_hparams_summary()
        super().save()
