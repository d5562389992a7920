"""A TensorBoard logger whose HParams tab shows the rollout metrics, not ``hp_metric = -1``."""

from __future__ import annotations

from typing import Any

from lightning.fabric.utilities.logger import _convert_params, _flatten_dict
from lightning.pytorch.loggers import TensorBoardLogger as _TensorBoardLogger
from lightning.pytorch.utilities.rank_zero import rank_zero_only


class TensorBoardLogger(_TensorBoardLogger):
    """Lightning's ``TensorBoardLogger`` that registers ``hp_metrics`` with the hparams.

    Lightning's logger registers a placeholder ``hp_metric`` (logged as -1) unless a
    metric value is passed with the hyperparameters, which at the start of a fit
    does not exist yet. This one writes the hparams summary with the metric *tags*
    ``hp_metrics`` (default ``rollout/energy_mse``): TensorBoard's HParams tab then
    reads their values from the scalars the rollout callback logs, and no fake
    value is written. Runs are told apart by ``name`` (e.g. ``spring_hnn``): logs go
    to ``save_dir/name/version_N``.

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

    @rank_zero_only
    def log_hyperparams(self, params: Any, metrics: dict[str, Any] | None = None) -> None:
        """Store ``params``; with ``metrics=None`` register :attr:`hp_metrics` as tags."""
        if metrics is not None or not self.hp_metrics:
            super().log_hyperparams(params, metrics)
            return
        super().log_hyperparams(params)
        from torch.utils.tensorboard.summary import hparams

        flat = self._sanitize_params(_flatten_dict(_convert_params(self.hparams)))
        writer = self.experiment.file_writer
        for summary in hparams(flat, dict.fromkeys(self.hp_metrics, 0.0)):
            writer.add_summary(summary)
