"""The measured pendulum of Schmidt & Lipson (2009), paper task 3.

The data (``hnn_pl/data/real_pend_h_1.txt``, provenance in
``hnn_pl/data/real_pendulum_SOURCE.md``) is one recorded trajectory: 556 samples of
time, angle ``θ`` and angular velocity ``θ̇``, used as ``(q, p)``.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import torch
from torch import Tensor

from hnn_pl.systems.pendulum import Pendulum

DATA_FILE = "real_pend_h_1.txt"


def load_real_pendulum(path: str | None = None) -> tuple[Tensor, Tensor]:
    """``t (556,)`` and ``y = (θ, θ̇) (556, 2)``, float64, from ``path`` (``None``: the
    packaged copy), a file with a header line ``%o v`` and rows ``trial t θ θ̇``."""
    if path is None:
        text = resources.files("hnn_pl.data").joinpath(DATA_FILE).read_text()
    else:
        text = Path(path).read_text()
    rows = [line.split() for line in text.splitlines()[1:] if line.strip()]
    table = torch.tensor([[float(v) for v in row] for row in rows], dtype=torch.float64)
    return table[:, 1].clone(), table[:, 2:4].clone()


class RealPendulum(Pendulum):
    """Energy ``E = 2.4 (1 − cos q) + p²`` of the measured pendulum, for evaluation only.

    2.4 is the reference code's *fit* to the data, not a measured constant, and the real
    pendulum loses energy to friction, so ``E`` is not exactly conserved: the limitation
    the paper states for HNNs. The dynamics come from the data
    (:func:`load_real_pendulum`); this class gives ``energy`` and the fitted ``H``.
    """

    def __init__(self, alpha: float = 2.4, beta: float = 1.0) -> None:
        super().__init__(alpha=alpha, beta=beta)

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        raise NotImplementedError("the real pendulum has one measured trajectory, no sampler")
