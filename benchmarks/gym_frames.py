"""The renderer against gym 0.12.1's own frames, and the fit of the torque-arrow ring.

``python benchmarks/gym_frames.py`` prints, for several renderer settings, the mean and
largest absolute difference from ``tests/data/gym_pendulum_frames.npz`` (701 angles,
0 … 128/255 scale) and the time to draw them. ``--fit`` refits
:data:`hnn_pl.render.GYM_ARROW_RING` (a few minutes, 1 thread).

The fit emulates the reference's pipeline at its own resolution: the scene point-sampled
at the pixel centres of the 340 × 340 crop of the 1000 × 1000 screen (``1000/4.4`` px per
world unit; this alone reproduces the frames gym drew without the arrow to a mean of
0.02 grey levels), the black ring multiplying the rod by ``1 − α``, then PIL's bilinear
340 → 28 down-sampling (a tent of half-width 340/28 px, weights renormalised at the
borders). ``α`` is a circular band of centre ``(cx, cy)``, radius and width, edges a
linear ramp of ``s`` screen pixels, opacity ``a``; Adam fits the six to the 701 frames
by squared error. Measured: centre (0.0259, 0.0392), radius 0.4446, width 0.0332,
``s`` ≈ 0.9 px, ``a`` → 1; mean difference 0.00023, max 0.012 (3 grey levels).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from hnn_pl.evaluation.metrics import max_abs_error, mean_abs_error
from hnn_pl.render import render_pendulum

FRAMES = Path(__file__).resolve().parents[1] / "tests" / "data" / "gym_pendulum_frames.npz"
PX = 1000 / 4.4  # screen pixels per world unit
ROWS, COLS = (440, 780), (330, 670)  # the reference's crop of the 1000 × 1000 screen


def load() -> tuple[torch.Tensor, torch.Tensor]:
    with np.load(FRAMES) as d:
        return torch.from_numpy(d["theta"]), torch.from_numpy(d["frames"]).double() / 255


def compare(theta: torch.Tensor, frames: torch.Tensor) -> None:
    settings = [
        ("box, k = 1, no band (old)", {"filter": "box", "supersample": 1, "arrow": False}),
        ("tent, k = 4, no band", {"arrow": False}),
        ("tent, k = 1, band", {"supersample": 1}),
        ("tent, k = 3, band", {"supersample": 3}),
        ("tent, k = 4, band (the default)", {}),
        ("tent, k = 8, band", {"supersample": 8}),
    ]  # fmt: skip
    print("| renderer | mean abs. difference | max | ms per 1000 frames (float32) |")
    print("|---|---|---|---|")
    for name, kw in settings:
        drawn = render_pendulum(theta, **kw)
        mean, worst = mean_abs_error(drawn, frames), max_abs_error(drawn, frames)
        t0 = time.perf_counter()
        render_pendulum(theta.float(), **kw)
        ms = (time.perf_counter() - t0) / len(theta) * 1e6
        print(f"| {name} | {mean:.5f} | {worst:.4f} | {ms:.0f} |")


def _tent(n_in: int = 340, n_out: int = 28) -> torch.Tensor:
    """PIL's bilinear resampling weights, ``(n_out, n_in)``."""
    scale = n_in / n_out
    x = torch.arange(n_in, dtype=torch.float64) + 0.5
    c = (torch.arange(n_out, dtype=torch.float64) + 0.5) * scale
    w = (1 - ((x.view(1, -1) - c.view(-1, 1)) / scale).abs()).clamp(min=0)
    return w / w.sum(1, keepdim=True)


def fit(theta: torch.Tensor, frames: torch.Tensor, steps: int = 400) -> list[float]:
    w = _tent()
    r = torch.arange(*ROWS, dtype=torch.float64) + 0.5
    c = torch.arange(*COLS, dtype=torch.float64) + 0.5
    x = (-2.2 + c / PX).view(1, 1, -1)  # world units, right
    y = (r / PX - 2.2).view(1, -1, 1)  # world units, below the pivot
    s, co = torch.sin(theta).view(-1, 1, 1), torch.cos(theta).view(-1, 1, 1)
    along, across = x * s + y * co, x * co - y * s
    excess = ((along - 0.5).abs() - 0.5).clamp(min=0)
    rod = (torch.hypot(across, excess) <= 0.1) & (torch.hypot(x, y) > 0.05)
    rod = rod.double() * 128 / 255
    base = w @ rod @ w.T
    rw, cw = slice(100, 200), slice(50, 290)  # the screen window the band can touch
    xs, ys, rods = x[..., cw], y[:, rw], rod[:, rw, cw]
    p = torch.tensor([0.0, 0.0, 0.48, 0.032, 0.0, 3.0], dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([p], lr=2e-3)
    for step in range(steps + 1):
        cx, cy, radius, width, log_s, logit_a = p
        rho = torch.hypot(xs - cx, ys - cy)
        ramp = ((width / 2 - (rho - radius).abs()) * PX / log_s.exp() + 0.5).clamp(0, 1)
        pred = base - w[:, rw] @ (rods * torch.sigmoid(logit_a) * ramp) @ w[:, cw].T
        loss = ((pred - frames) ** 2).mean()
        if step % 100 == 0:
            mean, worst = (
                mean_abs_error(pred.detach(), frames),
                max_abs_error(pred.detach(), frames),
            )
            print(f"step {step}: mean {mean:.5f}, max {worst:.4f}, p {p.tolist()}")
        opt.zero_grad()
        loss.backward()
        opt.step()
    return p.detach()[:4].tolist()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fit", action="store_true", help="refit the arrow's ring")
    args = parser.parse_args()
    torch.set_num_threads(1)
    theta, frames = load()
    compare(theta, frames)
    if args.fit:
        print("ring (cx, cy, radius, width):", fit(theta, frames))


if __name__ == "__main__":
    main()
