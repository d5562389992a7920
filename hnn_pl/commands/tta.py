"""The old home of :class:`~hnn_pl.experiments.tta.TimeToAccuracy`, kept so that configs
naming ``hnn_pl.commands.tta.TimeToAccuracy`` still load."""

from hnn_pl.experiments.tta import TimeToAccuracy

__all__ = ["TimeToAccuracy"]
