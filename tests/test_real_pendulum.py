"""The measured pendulum: the shipped file, forward differences, the reference split."""

from __future__ import annotations

import hashlib
from importlib import resources

import pytest
import torch

from hnn_pl.data import RealPendulumData
from hnn_pl.systems.real_pendulum import RealPendulum, load_real_pendulum

SHA256 = "45d92988198b89a5933f5a53e67aa819d06937516f71a462ac09e1307d8b3411"


def test_shipped_file_is_the_documented_one():
    raw = resources.files("hnn_pl.data").joinpath("real_pend_h_1.txt").read_bytes()
    assert hashlib.sha256(raw).hexdigest() == SHA256
    t, y = load_real_pendulum()
    assert t.shape == (556,) and y.shape == (556, 2) and y.dtype == torch.float64
    assert t[0] == 5.0 and t[-1] == 99.5
    gaps = (t[1:] - t[:-1]).mul(6).round()
    assert (gaps == 1).sum() == 545 and (gaps == 2).sum() == 8 and (gaps == 3).sum() == 2
    assert -1.41 < y[:, 0].min() < -1.40 and 1.47 < y[:, 0].max() < 1.48


def test_forward_differences_and_split_match_the_reference(tmp_path):
    dm = RealPendulumData(cache_dir=str(tmp_path), dtype="float64")
    dm.setup()
    t, y = load_real_pendulum()
    assert dm.x_train.shape == (445, 2) and dm.x_test.shape == (110, 2)
    torch.testing.assert_close(dm.x_test, y[444:554])
    torch.testing.assert_close(dm.x_train[-1], y[554])
    i = int(torch.nonzero((t[1:] - t[:-1]) > 0.3)[0])
    expected = (y[i + 1] - y[i]) / (t[i + 1] - t[i])
    row = dm.x_train if i < 444 else dm.x_test
    k = i if i < 444 else i - 444
    torch.testing.assert_close(row[k], y[i])
    assert dm.test_t[0] == 81.0 and abs(float(dm.test_t[-1]) - 99.1667) < 1e-3
    target = dm.dx_train if i < 444 else dm.dx_test
    torch.testing.assert_close(target[k], expected)
    assert dm.test_y.shape == (110, 1, 2)
    with pytest.raises(ValueError, match="t_end"):
        dm.rollout_target(20.0)


def test_energy_is_the_fitted_pendulum_and_decays_with_friction():
    _, y = load_real_pendulum()
    e = RealPendulum().energy(y)
    torch.testing.assert_close(e, 2.4 * (1 - torch.cos(y[:, 0])) + y[:, 1] ** 2)
    assert e[:50].mean() > e[-50:].mean()
