"""``predict``'s ``starts`` as positions windows: the observer infers the starts from
them, then the rollouts run as from given starts; bad files are refused in one line."""

from __future__ import annotations

import pytest
import torch
from torch import Tensor, nn

from hnn_pl.callbacks import RolloutWriter
from hnn_pl.commands.cli_errors import CLIError, check_starts
from hnn_pl.data import SimulatedData
from hnn_pl.evaluation.observer import read_positions_window
from hnn_pl.models import HNN
from hnn_pl.systems import Pendulum

F64 = torch.float64
T = torch.linspace(0, 3, 45, dtype=F64)[:15]  # the pendulum's first second


class ExactField(nn.Module):
    """The true pendulum as a model's ``field``."""

    def __init__(self) -> None:
        super().__init__()
        self.system = Pendulum()
        self.unit = nn.Parameter(torch.ones((), dtype=F64))

    def vector_field(self, t, y: Tensor) -> Tensor:
        return self.unit * self.system.vector_field(t, y)


def true_window(n: int = 4) -> tuple[Tensor, Tensor]:
    """Starts ``(n, 2)`` and their noise-free angles ``(n, 15, 1)`` over the first second."""
    system = Pendulum()
    y0 = system.sample_initial(n, torch.Generator().manual_seed(1))
    return y0, system.trajectory(y0, T)[..., :1].transpose(0, 1)


def write_csv(path, q: Tensor, t: Tensor, shift: float = 0.0) -> None:
    lines = [
        f"{b},{float(t[j]) + shift!r},{float(q[b, j, 0])!r}"
        for b in range(len(q))
        for j in range(q.shape[1])
    ]
    path.write_text("trajectory,time,q\n" + "\n".join(lines) + "\n")


@pytest.mark.parametrize("form", ["pt", "csv"])
def test_predict_infers_the_starts_from_a_positions_window(tmp_path, form):
    y0, q = true_window()
    path = tmp_path / f"window.{form}"
    if form == "pt":
        torch.save({"q": q, "t": T + 2.0}, path)
    else:
        write_csv(path, q, T, shift=2.0)
    check_starts(str(path), 2)
    dm = SimulatedData(Pendulum(), n_trajectories=4, n_points=10, observe="positions")
    dm.cache_dir = str(tmp_path)
    model = HNN(input_dim=2).double()
    model.field = ExactField()
    writer = RolloutWriter(task="pendulum", starts=str(path), overrides={"t_end": 1.0})
    out = writer._given_starts(model.eval(), dm)
    assert out["y"].shape[1:] == (4, 2)
    assert (out["y"][0] - y0).abs().max() < 1e-4  # each row's state at its first time
    torch.testing.assert_close(out["t0"], torch.full((4,), 2.0, dtype=F64))
    assert out["observed_rms"].max() < 1e-5
    truth = Pendulum().trajectory(y0, out["t"].to(F64))
    assert (out["y"] - truth).abs().max() < 1e-3


def test_a_window_dict_with_per_row_times_reads_back(tmp_path):
    _, q = true_window(2)
    t = torch.stack([T, 2 * T + 1])
    path = tmp_path / "w.pt"
    torch.save({"q": q, "t": t}, path)
    window = read_positions_window(path, 1)
    torch.testing.assert_close(window.t, t - t[:, :1])
    torch.testing.assert_close(window.t0, torch.tensor([0.0, 1.0], dtype=F64))


def _bad(tmp_path, name: str, content) -> str:
    path = tmp_path / name
    if isinstance(content, str):
        path.write_text(content)
    else:
        torch.save(content, path)
    return str(path)


_, Q = true_window(2)
CASES = {
    "missing key": ("w.pt", {"q": Q}, "a dict with keys ['q']"),
    "wrong k": ("w.pt", {"q": torch.cat([Q, Q], -1), "t": T}, "'q' has shape (2, 15, 2)"),
    "one sample": ("w.pt", {"q": Q[:, :1], "t": T[:1]}, "M >= 2"),
    "times shape": ("w.pt", {"q": Q, "t": T[:10]}, "'t' has shape (10,)"),
    "integer q": ("w.pt", {"q": Q.long(), "t": T}, "'q' is not a float tensor"),
    "not finite": (
        "w.pt",
        {"q": Q.clone().index_fill_(1, torch.tensor([3]), float("nan")), "t": T},
        "rows [0, 1] hold a value that is not finite",
    ),
    "times back": (
        "w.pt",
        {"q": Q, "t": T.flip(0)},
        "times not strictly increasing in rows [0, 1]",
    ),
    "states csv": ("w.csv", "trajectory,time,q,p\n0,0,1,2\n0,1,3,4\n", "holds states (q, p)"),
    "bad csv cell": ("w.csv", "trajectory,time,q\n0,0,1\n0,1,abc\n", "line 3"),
    "a list": ("w.pt", [1, 2], "holds a list"),
}


@pytest.mark.parametrize("case", CASES, ids=list(CASES))
def test_a_bad_window_is_refused_in_one_line_naming_the_file(tmp_path, case):
    name, content, says = CASES[case]
    path = _bad(tmp_path, name, content)
    with pytest.raises(CLIError) as err:
        check_starts(path, 2)
    line = str(err.value)
    assert "\n" not in line and line.startswith(f"starts {path}") and says in line, line
