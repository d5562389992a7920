"""The measured pendulum's data (paper task 3)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from hnn_pl.data.recording import (
    Recording,
    RecordingData,
    differences,
    load_recording,
    recording_from_arrays,
)
from hnn_pl.systems.real_pendulum import RealPendulum, load_real_pendulum

#: the measured trajectory as a recording (:mod:`hnn_pl.data.recording`)
RECORDING_FILE = "real_pendulum.csv"


class RealPendulumData(RecordingData):
    """Finite differences of the measured trajectory, split as the reference.

    The shipped recording ``hnn_pl/data/real_pendulum.csv`` (one trajectory,
    the numbers of ``real_pend_h_1.txt``). With states ``y_i = (θ_i, θ̇_i)`` at times
    ``t_i`` (556 samples, mostly ``Δt = 1/6``), inputs are ``y_i`` and targets
    ``(y_{i+1} − y_i)/(t_{i+1} − t_i)``
    with the real gaps: 555 pairs (``differences="forward"``, the paper's). Forward
    differences of an oscillation are biased towards decay: for ``y = e^{iωt}`` they
    give ``(e^{iωΔt} − 1)/Δt``, whose real part ``−(1 − cos ωΔt)/Δt`` reads as friction
    a model with a dissipative term learns. ``differences="central"`` uses
    ``x_i = y_{i+1}``, ``(y_{i+2} − y_i)/(t_{i+2} − t_i)`` (554 pairs, ``i`` indexed as
    before): ``i sin(ωΔt)/Δt``, no spurious decay. Test = pairs ``test_start … test_stop − 1``
    (default 444…553: 110 pairs, ``t`` = 81.0 … 99.17), train = every other pair
    (445). The held-out trajectory for rollouts is the measured segment itself,
    ``test_y (110, 1, 2)`` at ``test_t (110,)``; there is no ground truth beyond
    it. Energy: :class:`~hnn_pl.systems.real_pendulum.RealPendulum` (fitted).

    Observed trajectories (``obs_*``, ``window``; no differences): the held-out
    segment is the samples of ``test_t`` (forward: ``test_start … test_stop − 1``,
    central: one later); the samples before and after it (those pieces of at least
    two samples) are the training trajectories — forward by default: 444 and 2
    samples.

    Args:
        path: a recording (``.csv``, ``.npz``, ``.pt``) or a file of the original
            ``.txt`` format (``None``: the shipped recording).
        test_start, test_stop: the held-out pairs ``[test_start, test_stop)``.
        differences: ``"forward"`` (paper) or ``"central"``.
        **kwargs: the data options of :class:`~hnn_pl.data.base.TrajectoryDataModule`
            (``batch_size``, ``seed``, ``dtype``, ``window``, ``observe``, …).
    """

    def __init__(
        self,
        path: str | None = None,
        test_start: int = 444,
        test_stop: int = 554,
        differences: str = "forward",
        **kwargs,
    ) -> None:
        self.test_start, self.test_stop = test_start, test_stop
        super().__init__(path, RealPendulum(), 0.2, None, None, differences, **kwargs)
        for name in ("test_fraction", "test_trajectories", "test_segment"):
            self.hparams.pop(name, None)  # RecordingData's, not options of this class

    def read(self, path: str | None) -> Recording:
        """The shipped recording (``None``), a ``.txt`` of the original format, or a
        recording file, on the file's own time axis (the reference's split times: not
        shifted, ``t0 = 0``), checked to fit the served dtype."""
        if path is None:
            with resources.as_file(resources.files("hnn_pl.data") / RECORDING_FILE) as shipped:
                return load_recording(shipped, self.dtype, shift=False)
        if Path(path).suffix != ".txt":
            return load_recording(path, self.dtype, shift=False)
        t, y = load_real_pendulum(path)
        ids = np.zeros(len(t), dtype=np.int64)
        return recording_from_arrays(path, ids, t.numpy(), y.numpy(), dtype=self.dtype, shift=False)

    def _split(self, *_: Any) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
        """The samples of ``test_t`` held out (central differences: one later)."""
        shift = int(self.differences == "central")
        return self.segment_split(self.test_start + shift, self.test_stop + shift)

    def generate(self) -> dict[str, Tensor]:
        data = super().generate()
        x, dx = differences(self.recording.t, self.recording.y, self.differences)
        a, b = self.test_start, self.test_stop
        train = list(range(a)) + list(range(b, len(x)))
        pairs = {"x_train": x[train], "dx_train": dx[train], "x_test": x[a:b], "dx_test": dx[a:b]}
        return {**data, **pairs}

    def true_field(self, t: Tensor, y: Tensor) -> Tensor:
        """The measured ``dy/dt`` along a recorded segment ``y (T, B, D)`` at ``t (T,)``:
        second-order central differences with the real gaps (one-sided at the ends,
        ``torch.gradient``); the fitted energy's conservative field would hide the
        friction the recording has."""
        return torch.gradient(y, spacing=(t.to(y.dtype),), dim=0)[0]
