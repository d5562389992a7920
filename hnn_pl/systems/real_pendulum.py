"""The measured pendulum of Schmidt & Lipson (2009), paper task 3.

The data (``hnn_pl/data/real_pend_h_1.txt``, provenance in
``hnn_pl/data/real_pendulum_SOURCE.md``) is one recorded trajectory: 556 samples of
time, angle ``θ`` and angular velocity ``θ̇``, used as ``(q, p)``.
"""

from __future__ import annotations

from importlib import resources

import torch
from torch import Tensor

from hnn_pl.systems.pendulum import Pendulum

DATA_FILE = "real_pend_h_1.txt"


def load_real_pendulum(path: str | None = None) -> tuple[Tensor, Tensor]:
    """Read the measured trajectory (float64).

    The file has a header line ``%o v`` and rows ``trial t θ θ̇``.

    Args:
        path: a file of that format; ``None`` reads the copy shipped in the package.

    Returns:
        ``t (556,)`` and ``y = (θ, θ̇)`` of shape ``(556, 2)``.
    """
    if path is None:
        text = resources.files("hnn_pl.data").joinpath(DATA_FILE).read_text()
    else:
        with open(path) as f:
            text = f.read()
    rows = [line.split() for line in text.splitlines()[1:] if line.strip()]
    table = torch.tensor([[float(v) for v in row] for row in rows], dtype=torch.float64)
    return table[:, 1].clone(), table[:, 2:4].clone()


class RealPendulum(Pendulum):
    """Energy ``E = 2.4 (1 − cos q) + p²`` of the measured pendulum, for evaluation only.

    The coefficient 2.4 is the reference code's *fit* to the data, not a measured
    constant, and the real pendulum loses energy to friction: its trajectories do
    not conserve ``E`` exactly, which is the limitation the paper states for HNNs
    (they learn a conserved quantity by construction). The dynamics come from the
    data (:func:`load_real_pendulum`); this class provides ``energy`` and the
    ``H`` of that fitted ideal pendulum.
    """

    def __init__(self, alpha: float = 2.4, beta: float = 1.0) -> None:
        super().__init__(alpha=alpha, beta=beta)

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        raise NotImplementedError("the real pendulum has one measured trajectory, no sampler")
