"""Pixel pendulum: renderer, gym dynamics, energy, sampling, autoencoder, PNG writer."""

from __future__ import annotations

import math
import struct
import zlib
from pathlib import Path

import pytest
import torch

from hnn_pl.experiments.report import save_png
from hnn_pl.nets.autoencoder import PixelDecoder, PixelEncoder
from hnn_pl.render import (
    GYM_ARROW_RING,
    GYM_CROP_X,
    GYM_CROP_Y,
    GYM_INTENSITY,
    frame_strip,
    render_pendulum,
)
from hnn_pl.systems.pixel_pendulum import PixelPendulum, simulate_gym_pendulum


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    """Small tensors: one thread is as fast, and far faster when the cores are busy."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


R, L, AXLE, I0 = 0.1, 1.0, 0.05, GYM_INTENSITY  # rod radius, length, axle radius, intensity
#: the plain scene: no arrow band, one sample per pixel, box filter (the old default)
BOX = {"filter": "box", "supersample": 1, "arrow": False}
PLAIN = {"arrow": False}
PIX = (GYM_CROP_X[1] - GYM_CROP_X[0]) / 28  # world units per pixel of the default crop
# capsule minus axle disc: area and distance of its centroid from the pivot along the rod
AREA = 2 * R * L + math.pi * R**2 - math.pi * AXLE**2
S_BAR = (R * L**2 + math.pi * R**2 * L / 2) / AREA


def pixel_centres(size=28, x_range=GYM_CROP_X, y_range=GYM_CROP_Y):
    """World coordinates (x right, y down from the pivot) of the pixel centres."""
    hx = (x_range[1] - x_range[0]) / size
    hy = (y_range[1] - y_range[0]) / size
    xs = x_range[0] + (torch.arange(size, dtype=torch.float64) + 0.5) * hx
    ys = y_range[0] + (torch.arange(size, dtype=torch.float64) + 0.5) * hy
    return xs.view(1, -1).expand(size, size), ys.view(-1, 1).expand(size, size)


def distance_to_rod(theta: float, size=28, **window):
    """Distance of each pixel centre to the rod's axis segment, computed independently."""
    x, y = pixel_centres(size, **window)
    tip = torch.tensor([math.sin(theta), math.cos(theta)], dtype=torch.float64) * L
    p = torch.stack([x, y], -1)
    t = (p @ tip / (L * L)).clamp(0, 1)
    return (p - t[..., None] * tip).norm(dim=-1)


def centroid(frames):
    """Intensity-weighted (row, col) centroid in pixel-index coordinates."""
    size = frames.shape[-1]
    idx = torch.arange(size, dtype=frames.dtype)
    m = frames.sum((-1, -2))
    return (frames.sum(-1) * idx).sum(-1) / m, (frames.sum(-2) * idx).sum(-1) / m


def expected_centroid(theta, size=28, x_range=GYM_CROP_X, y_range=GYM_CROP_Y):
    """Analytic centroid of the capsule minus the axle, in pixel-index coordinates."""
    hx = (x_range[1] - x_range[0]) / size
    hy = (y_range[1] - y_range[0]) / size
    col = (S_BAR * torch.sin(theta) - x_range[0]) / hx - 0.5
    row = (S_BAR * torch.cos(theta) - y_range[0]) / hy - 0.5
    return row, col


# --------------------------------------------------------------------------- renderer


def test_shapes_and_dtypes():
    assert render_pendulum(torch.tensor(0.3)).shape == (28, 28)
    th = torch.linspace(-1, 1, 6).view(2, 3)
    assert render_pendulum(th).shape == (2, 3, 28, 28)
    assert render_pendulum(th, size=16).shape == (2, 3, 16, 16)
    assert render_pendulum(th).dtype == torch.float32
    assert render_pendulum(th.double()).dtype == torch.float64
    assert render_pendulum(torch.tensor([0, 1])).dtype == torch.get_default_dtype()
    assert render_pendulum(torch.zeros(0)).shape == (0, 28, 28)
    # chunking does not change the result
    many = torch.linspace(-1.5, 1.5, 50, dtype=torch.float64)
    torch.testing.assert_close(render_pendulum(many, chunk=7), render_pendulum(many))


@pytest.mark.parametrize("filt", ["box", "tent"])
def test_values_background_and_peak(filt):
    for theta in [-1.2, -0.4, 0.0, 0.25, 0.9]:
        f = render_pendulum(torch.tensor(theta, dtype=torch.float64), **{**BOX, "filter": filt})
        assert f.min() >= 0 and f.max() <= I0 + 1e-12
        d = distance_to_rod(theta)
        reach = 0.5 if filt == "box" else 1.0  # half-width of the filter, pixels
        far = d > R + reach * PIX + 1e-9
        assert far.sum() > 500
        assert (f[far] == 0).all(), "background must be exactly 0 away from the rod"
        # pixels well inside the rod and away from the axle hole are exactly the intensity
        inside = (d < R - reach * PIX - 1e-9) & (torch.hypot(*pixel_centres()) > AXLE + 2 * PIX)
        assert inside.sum() >= 10
        torch.testing.assert_close(f[inside], torch.full_like(f[inside], I0), atol=1e-12, rtol=0)
        assert f.max() == pytest.approx(I0, abs=1e-12)


def test_intensity_parameter_scales_and_axle_hole():
    th = torch.tensor(0.2, dtype=torch.float64)
    torch.testing.assert_close(render_pendulum(th, intensity=2 * I0), 2 * render_pendulum(th))
    whole, holed = render_pendulum(th, axle_radius=0.0, **BOX), render_pendulum(th, **BOX)
    diff = whole - holed
    assert (diff >= -1e-12).all()
    # the hole has the axle's area (the 1-px ramp overestimates a 0.94-px disc by ~6 %)
    assert diff.sum() * PIX**2 == pytest.approx(I0 * math.pi * AXLE**2, rel=0.1)
    kw = {**BOX, "supersample": 8}
    fine = render_pendulum(th, axle_radius=0.0, **kw) - render_pendulum(th, **kw)
    assert fine.sum() * PIX**2 == pytest.approx(I0 * math.pi * AXLE**2, rel=0.02)
    # and sits at the pivot: pixel (i, j) = (4.44, 13.5) in index coordinates
    r, c = centroid(diff)
    assert float(r) == pytest.approx(-GYM_CROP_Y[0] / PIX - 0.5, abs=0.05)
    assert float(c) == pytest.approx(13.5, abs=0.05)


def test_centroid_follows_geometry_in_default_crop():
    # the rod stays inside the crop for |θ| < 0.70 (tip + cap reaches x = 0.748)
    theta = torch.linspace(-0.65, 0.65, 27, dtype=torch.float64)
    row, col = centroid(render_pendulum(theta, **PLAIN))
    erow, ecol = expected_centroid(theta)
    assert (row - erow).abs().max() < 0.15
    assert (col - ecol).abs().max() < 0.15
    # sign convention: θ > 0 swings the rod to the right (larger column index)
    assert (col[theta > 0.05] > 14).all() and (col[theta < -0.05] < 13).all()


def test_centroid_over_half_circle_in_wide_window():
    win = {"x_range": (-1.3, 1.3), "y_range": (-0.3, 2.3)}
    theta = torch.linspace(-math.pi / 2 + 0.01, math.pi / 2 - 0.01, 41, dtype=torch.float64)
    row, col = centroid(render_pendulum(theta, size=48, **win, **PLAIN))
    erow, ecol = expected_centroid(theta, size=48, **win)
    assert (row - erow).abs().max() < 0.15
    assert (col - ecol).abs().max() < 0.15


def test_mirror_symmetry():
    theta = torch.linspace(0.0, math.pi, 13, dtype=torch.float64)
    for filt in ("box", "tent"):
        a = render_pendulum(-theta, **{**BOX, "filter": filt})
        b = render_pendulum(theta, **{**BOX, "filter": filt}).flip(-1)
        torch.testing.assert_close(a, b, atol=1e-12, rtol=0)
    assert not torch.allclose(
        render_pendulum(torch.tensor(0.4)), render_pendulum(-torch.tensor(0.4))
    )


@pytest.mark.parametrize(
    ("filt", "k", "rel"), [("box", 1, 0.01), ("tent", 1, 0.01), ("box", 4, 0.003)]
)
def test_total_intensity_is_rod_area(filt, k, rel):
    theta = torch.linspace(-0.65, 0.65, 53, dtype=torch.float64)
    total = render_pendulum(theta, filter=filt, supersample=k, arrow=False).sum((-1, -2))
    expected = I0 * AREA / PIX**2  # ≈ 39.1
    assert ((total - expected).abs() / expected).max() < rel


def test_supersampling_converges():
    theta = torch.linspace(-0.6, 0.6, 7, dtype=torch.float64)
    exact = render_pendulum(theta, **{**BOX, "supersample": 12})
    err1 = (render_pendulum(theta, **BOX) - exact).abs().max()  # measured 0.031
    err4 = (render_pendulum(theta, **{**BOX, "supersample": 4}) - exact).abs().max()  # 0.005
    assert err4 < err1 and err4 < 0.02 * I0 and err1 < 0.1 * I0
    # the analytic tent ramp approximates the separable tent within ~0.1 · intensity
    tent = render_pendulum(theta, filter="tent", supersample=8, arrow=False)
    tent1 = render_pendulum(theta, filter="tent", supersample=1, arrow=False)
    torch.testing.assert_close(tent1, tent, atol=0.15 * I0, rtol=0)
    torch.testing.assert_close(tent.sum((-1, -2)), exact.sum((-1, -2)), rtol=2e-3, atol=0)


def test_anti_aliasing_small_change_gives_small_nonzero_change():
    th = torch.tensor([0.3, 0.3 + 1e-3], dtype=torch.float64)
    f = render_pendulum(th, **BOX)
    diff = (f[1] - f[0]).abs()
    # the tip moves 1e-3 units = 0.019 px; a pixel changes at most by I0 · 0.019 · √2
    assert 0 < diff.max() < 0.02
    assert (diff > 1e-6).sum() >= 10  # both long edges move, not a single snapped pixel
    # and the change is linear in the step (no snapping thresholds)
    g = render_pendulum(torch.tensor([0.3, 0.3 + 2e-3], dtype=torch.float64), **BOX)
    torch.testing.assert_close((g[1] - g[0]).abs().sum(), 2 * diff.sum(), rtol=0.05, atol=0)


REFERENCE_FRAMES = Path(__file__).parent / "data" / "gym_pendulum_frames.npz"


@pytest.fixture(scope="module")
def reference_frames():
    """The frames gym 0.12.1's own renderer made, processed as the reference did
    (``tests/data/gym_pendulum_frames_SOURCE.md``): angles and frames on 0 … 128/255."""
    import numpy as np

    with np.load(REFERENCE_FRAMES) as d:
        data = {k: torch.from_numpy(d[k]) for k in d.files}
    for k in ("frames", "frames_with_arrow", "frames_without_arrow"):
        data[k] = data[k].double() / 255
    return data


def test_reproduces_reference_frames(reference_frames):
    """All 701 angles |θ| ≤ 0.7 of gym's real renderer, with its torque-arrow band."""
    ref = reference_frames
    assert ref["frames"].shape == (701, 28, 28) and ref["frames"].max() == I0
    err = (render_pendulum(ref["theta"]) - ref["frames"]).abs()
    assert err.mean() <= 1e-3 and err.max() <= 0.05  # measured 0.00048, 0.020
    # the band and the filter are what it takes: the old renderer misses by far more
    old = (render_pendulum(ref["theta"], **BOX) - ref["frames"]).abs()
    assert old.mean() > 4 * err.mean() and old.max() > 0.25


def test_reference_frames_with_and_without_arrow(reference_frames):
    """gym drew the arrow at u = 0; the six frames made without it match ``arrow=False``."""
    ref = reference_frames
    th = ref["theta_arrow_check"]
    for arrow, key in ((True, "frames_with_arrow"), (False, "frames_without_arrow")):
        err = (render_pendulum(th, arrow=arrow) - ref[key]).abs()
        assert err.mean() <= 1e-3 and err.max() <= 0.05, key
    # the band: darker along the rod, nowhere brighter, at the ring's distance from the pivot
    band = render_pendulum(th, arrow=False) - render_pendulum(th)
    ref_band = ref["frames_without_arrow"] - ref["frames_with_arrow"]
    assert (band >= -1e-12).all() and band.amax((-1, -2)).min() > 0.15  # 0.18 … 0.26
    # measured 1.17–1.18 against 1.11–1.15: the drawn arrow is not quite a uniform ring
    torch.testing.assert_close(band.sum((-1, -2)), ref_band.sum((-1, -2)), rtol=0.1, atol=0)
    cx, cy, radius, band_width = GYM_ARROW_RING
    # its total is the rod's crossing of the ring: width · band_width (the rod crosses
    # the ring nearly at right angles), in pixels of the crop
    total = band.sum((-1, -2)) * PIX**2 / I0
    torch.testing.assert_close(total, torch.full_like(total, 2 * R * band_width), rtol=0.05, atol=0)
    row, col = centroid(band)
    pivot_row, pivot_col = -GYM_CROP_Y[0] / PIX - 0.5, 13.5
    dist = torch.hypot(row - pivot_row, col - pivot_col) * PIX
    assert ((dist - radius).abs() < 0.06).all()


def _read_png(data: bytes):
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, chunks = 8, []
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos : pos + 4])
        tag, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + n]
        (crc,) = struct.unpack(">I", data[pos + 8 + n : pos + 12 + n])
        assert crc == zlib.crc32(tag + body)
        chunks.append((tag, body))
        pos += 12 + n
    assert [c[0] for c in chunks] == [b"IHDR", b"IDAT", b"IEND"]
    w, h, depth, ctype = struct.unpack(">IIBB", chunks[0][1][:10])
    raw = zlib.decompress(chunks[1][1])
    return w, h, depth, ctype, raw


def test_save_png_round_trip(tmp_path):
    frames = render_pendulum(torch.linspace(-1, 1, 3))
    img = frame_strip(frames, scale=2, gap=1)
    assert img.dtype == torch.uint8 and img.shape == (56, 3 * 56 + 2)
    assert img.max() == 255 and (img[:, 56] == 128).all()
    save_png(tmp_path / "a.png", img)
    w, h, depth, ctype, raw = _read_png((tmp_path / "a.png").read_bytes())
    assert (w, h, depth, ctype) == (170, 56, 8, 0)
    rows = torch.frombuffer(bytearray(raw), dtype=torch.uint8).view(h, w + 1)
    assert (rows[:, 0] == 0).all() and torch.equal(rows[:, 1:], img)
    rgb = torch.randint(0, 256, (5, 7, 3), dtype=torch.uint8)
    save_png(tmp_path / "b.png", rgb)
    w, h, _, ctype, raw = _read_png((tmp_path / "b.png").read_bytes())
    assert (w, h, ctype) == (7, 5, 2)
    assert torch.equal(torch.frombuffer(bytearray(raw), dtype=torch.uint8).view(5, 22)[:, 1:],
                       rgb.view(5, 21))  # fmt: skip
    with pytest.raises(ValueError):
        save_png(tmp_path / "c.png", torch.rand(4, 4))


# --------------------------------------------------------------------------- dynamics


def gym_step(th_gym, thdot, g=10.0, l=1.0, m=1.0, dt=0.05, u=0.0, max_speed=8.0):
    """Literal transcription of Pendulum-v0's ``step`` (θ = 0 upright)."""
    newthdot = thdot + (-3 * g / (2 * l) * math.sin(th_gym + math.pi) + 3.0 / (m * l**2) * u) * dt
    newth = th_gym + newthdot * dt
    newthdot = min(max(newthdot, -max_speed), max_speed)
    return newth, newthdot


@pytest.mark.parametrize(("th0", "om0"), [(0.3, -0.7), (-2.5, 0.0), (0.1, 9.9), (3.0, -7.95)])
def test_matches_gym_step(th0, om0):
    theta, omega = simulate_gym_pendulum(torch.tensor(th0, dtype=torch.float64), om0, 60)
    th, om = th0 + math.pi, om0  # gym's angle is ours + π
    for n in range(1, 61):
        th, om = gym_step(th, om)
        assert float(theta[n]) == pytest.approx(th - math.pi, abs=1e-12)
        assert float(omega[n]) == pytest.approx(om, abs=1e-12)
    assert omega[1:].abs().max() <= 8.0


def test_clip_happens_after_the_angle_update():
    theta, omega = simulate_gym_pendulum(torch.tensor(0.0, dtype=torch.float64), 10.0, 1)
    assert float(omega[1]) == 8.0
    assert float(theta[1]) == pytest.approx(10.0 * 0.05, abs=1e-15)  # unclipped ω used


def test_shapes_wrap_and_broadcast():
    th0 = torch.zeros(4, 3, dtype=torch.float64)
    theta, omega = simulate_gym_pendulum(th0, torch.tensor([7.95, 0.0, -7.95]), 200)
    assert theta.shape == omega.shape == (4, 3, 201) and theta.dtype == torch.float64
    assert theta[0, 0].max() > math.pi  # it turns over: gym's angle is not normalised
    wrapped, _ = simulate_gym_pendulum(th0, torch.tensor([7.95, 0.0, -7.95]), 200, wrap=True)
    assert wrapped.min() >= -math.pi and wrapped.max() < math.pi
    torch.testing.assert_close(torch.cos(wrapped), torch.cos(theta))


def test_energy_bounded_without_drift():
    pend = PixelPendulum()
    th0, om0 = pend.sample_initial(200, torch.Generator().manual_seed(1))
    theta, omega = pend.simulate(th0, om0, 102)
    e = pend.energy(pend.to_canonical(theta, omega))
    rel = (e - e[:, :1]) / e[:, :1]
    # semi-implicit Euler: H itself oscillates by O(ω dt) ~ 20 %, but does not drift ...
    assert rel.abs().max() < 0.3
    drift = (e[:, -32:].mean(-1) - e[:, :32].mean(-1)) / e[:, 0]
    assert drift.abs().max() < 0.01
    # ... because the map conserves a modified energy to O(dt²)
    k, dt = 15.0, 0.05
    h_mod = omega**2 / 2 + k * (1 - torch.cos(theta)) - dt / 2 * k * torch.sin(theta) * omega
    assert ((h_mod - h_mod[:, :1]) / h_mod[:, :1]).abs().max() < 2e-3


def test_small_angle_period():
    theta, _ = simulate_gym_pendulum(torch.tensor(0.01, dtype=torch.float64), 0.0, 102)
    th = theta.numpy()
    crossings = [
        n + th[n] / (th[n] - th[n + 1]) for n in range(len(th) - 1) if th[n] > 0 >= th[n + 1]
    ]
    assert len(crossings) >= 3
    period = (crossings[-1] - crossings[0]) / (len(crossings) - 1) * 0.05
    assert period == pytest.approx(2 * math.pi / math.sqrt(3 * 10.0 / 2), rel=0.01)


def test_sample_initial_and_canonical():
    pend = PixelPendulum()
    th0, om0 = pend.sample_initial(4000, torch.Generator().manual_seed(0))
    assert th0.shape == om0.shape == (4000,) and th0.dtype == om0.dtype == torch.float64
    assert th0.abs().max() < math.pi / 6 and th0.abs().max() > 0.99 * math.pi / 6
    assert om0.abs().max() < 1 and om0.abs().max() > 0.99
    assert abs(float(th0.mean())) < 0.03 and abs(float(om0.mean())) < 0.05
    again = pend.sample_initial(4000, torch.Generator().manual_seed(0))
    assert torch.equal(again[0], th0) and torch.equal(again[1], om0)
    other = pend.sample_initial(4000, torch.Generator().manual_seed(1))
    assert not torch.equal(other[0], th0)
    y = pend.to_canonical(th0, om0)
    assert y.shape == (4000, 2)
    torch.testing.assert_close(y[:, 1], 0.25 * om0)
    assert pend.energy_coef == 1.875 and PixelPendulum(energy_coef=1.9).energy_coef == 1.9
    torch.testing.assert_close(pend.energy(y), pend.energy(y[:, 0], y[:, 1]))
    torch.testing.assert_close(pend.energy(y), 1.875 * (1 - torch.cos(th0)) + (0.25 * om0) ** 2)


# --------------------------------------------------------------------------- autoencoder


def test_autoencoder_shapes_and_init():
    enc, dec = PixelEncoder(), PixelDecoder()
    x = torch.rand(5, 1568)
    z = enc(x)
    assert z.shape == (5, 2) and dec(z).shape == (5, 1568)
    assert dec(enc(torch.rand(3, 4, 1568))).shape == (3, 4, 1568)
    w = enc.linear1.weight  # (200, 1568): orthonormal rows
    torch.testing.assert_close(w @ w.T, torch.eye(200), atol=1e-5, rtol=0)
    assert sum(p.numel() for p in enc.parameters()) == 1568 * 200 + 2 * 200 * 200 + 200 * 2 + 602
    # linear output, no sigmoid: values outside [0, 1] are reachable
    out = dec(torch.tensor([[30.0, -30.0]]))
    assert out.min() < 0 or out.max() > 1
    with pytest.raises(ValueError):
        PixelEncoder(activation="gelu")


def test_autoencoder_learns_rendered_frames():
    torch.manual_seed(0)
    gen = torch.Generator().manual_seed(0)
    n = 100
    theta = (torch.rand(n, generator=gen) - 0.5) * 1.2
    omega = torch.rand(n, generator=gen) * 2 - 1
    x = torch.cat([render_pendulum(theta), render_pendulum(theta + 0.05 * omega)], -1)
    x = x.reshape(n, 1568)
    enc, dec = PixelEncoder(), PixelDecoder()
    opt = torch.optim.Adam([*enc.parameters(), *dec.parameters()], lr=1e-3)
    with torch.no_grad():
        before = float(((dec(enc(x)) - x) ** 2).mean())
    for _ in range(100):
        loss = ((dec(enc(x)) - x) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        after = float(((dec(enc(x)) - x) ** 2).mean())
    # far below the start and well below the best constant image (per-pixel variance)
    assert after < 0.1 * before
    assert after < 0.3 * float(x.var(0).mean())
