"""Pure-torch renderer of gym Pendulum-v0's scene, drawn directly at ``size × size``.

The reference (``experiment-pixels/data.py``) renders gym's pyglet viewer, keeps red
minus green, crops and resizes with ``scipy.misc.imresize``; none of that runs on a
current stack. :func:`render_pendulum` draws the same scene analytically, batched and
anti-aliased by pixel coverage; :func:`frame_strip` tiles frames
(``python -m hnn_pl.experiments.report`` draws ``docs/pixel_frames.png`` with it).

Scene (gym ``PendulumEnv.render``, Pendulum-v0 era)::

    viewer = rendering.Viewer(500, 500); viewer.set_bounds(-2.2, 2.2, -2.2, 2.2)
    rod = rendering.make_capsule(1, .2); rod.set_color(.8, .3, .3)
    axle = rendering.make_circle(.05); axle.set_color(0, 0, 0)
    self.pole_transform.set_rotation(self.state[0] + np.pi/2)

``R − G`` is 0 on the background and on the black axle (a small hole in the rod, drawn
after it) and ``204 − 76 = 128`` of 255 on the rod; gym's torque arrow, black, leaves
a band across the rod (``arrow``). The reference's crop
``X[440:-220, 330:-330]`` of the 1000 × 1000 framebuffer (a 2× HiDPI screen; the crop
needs more than 500 rows) at ``1000 / 4.4`` px per world unit is the window
:data:`GYM_CROP_X`, :data:`GYM_CROP_Y`, which ``imresize`` (PIL bilinear) shrinks to 28 × 28.

**Geometry.** ``θ = 0`` hangs straight down, ``θ > 0`` swings the rod to the image's
**right** (``+x``) as in gym's viewer and the reference's ``get_theta``
(``θ = θ_gym − π``): the tip is at ``length·(sin θ, cos θ)`` in image coordinates
(``x`` right, ``y`` down). The rod is a capsule (all points within ``width/2`` of the
pivot-tip segment) of value ``intensity`` on 0, minus the axle disc (drawn on top).

**World → pixel.** The window ``x ∈ [x0, x1]``, ``y ∈ [y0, y1]`` (world units about
the pivot, ``y`` down; default the reference crop, ``x ∈ ±0.748``,
``y ∈ [−0.264, 1.232]``) is cut into ``size × size`` pixels of
``hx = (x1 − x0)/size`` by ``hy = (y1 − y0)/size``: pixel ``[i, j]`` (row from the
top, column from the left) has its centre at ``(x0 + (j + ½)hx, y0 + (i + ½)hy)``.
With the defaults a pixel is 0.0534 units, the rod 18.7 px long and 3.7 px wide and
the pivot at ``(i, j) = (4.44, 13.5)``.

**Anti-aliasing.** A pixel holds ``intensity ×`` the ramp ``clamp(½ − d/h, 0, 1)`` of
the signed distance ``d`` of its centre to the capsule (and the axle), ``h = √(hx·hy)``:
exact coverage for straight axis-aligned edges, else off by ≤ ~0.06·intensity per
pixel and < 0.5 % per frame. ``supersample = k > 1`` averages ``k × k`` sub-pixels
(``k = 4``: ≤ 0.012·intensity, ``k²`` times the cost). ``filter = "tent"`` sees the
scene through a tent of half-width 1 pixel, as PIL's bilinear 340 → 28 px
down-sampling did to the reference frames (softer edges, same total): a 1-D tent
profile of ``d`` for ``k = 1`` (within ~0.1·intensity of the 2-D tent), the exact
separable tent over the sub-pixels for ``k > 1``. Centres more than ½ px (box) or
1 px (tent) inside the rod give ``intensity``, as far outside exactly 0.

**The torque arrow.** gym 0.12 draws its ``clockwise.png`` arrow (1 × 1 world units
at the pivot, above the rod) in every frame the reference made: it scales the arrow
away only when ``last_u`` is truthy, and the reference steps with ``u = 0``. Black
over the rod, it leaves a dark band across it about 0.45 units from the pivot;
``arrow=True`` multiplies the rod by ``1 − coverage`` of the band ``ring = (cx, cy,
radius, width)``: all points whose distance to ``(cx, cy)`` (world units, ``y`` down)
is within ``width/2`` of ``radius``, default :data:`GYM_ARROW_RING`. Only the part
the hanging rod crosses is modelled, measured for ``|θ| ≤ 0.7`` (the pixel task's
pendulum, ``|θ₀| < π/6`` and ``|θ̇₀| < 1``, swings less than 0.59); the arrow's
head is not drawn.

**Faithfulness.** The defaults (tent, ``k = 4``, the band, intensity ``128/255``)
reproduce the reference's frames (gym 0.12.1 under a virtual display, red − green,
crop, PIL bilinear, ``tests/data/gym_pendulum_frames.npz``): mean absolute
difference 0.00048, max 0.020 over 701 angles ``|θ| ≤ 0.7`` (``k = 1`` box without
the band, the old default: 0.0046, 0.28). Not modelled: the reference's 8-bit
quantisation (±0.002; rounding changes the mean difference by < 1e-5).

**Speed.** Frames are drawn in chunks of as many as keep each elementwise op under
PyTorch's parallelisation grain (32 768 elements, 41 frames of 28 × 28), so each runs
on one thread (3–10 × faster than 1024-frame batches on 2 busy cores), but at least 16
(per-op overhead dominates below that: 16 frames at ``k = 4`` in float32 are 1.7 ×
faster than 2).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

#: pixels per world unit of the framebuffer the reference cropped (1000 px over 4.4 units)
_REF_PX = 1000 / 4.4
#: horizontal extent of the reference crop, world units about the pivot (±170 px)
GYM_CROP_X: tuple[float, float] = (-170 / _REF_PX, 170 / _REF_PX)
#: vertical extent, world units *below* the pivot (60 px above to 280 px below it)
GYM_CROP_Y: tuple[float, float] = (-60 / _REF_PX, 280 / _REF_PX)

_FILTERS = ("box", "tent")

#: ``R − G`` of gym's rod colour (.8, .3, .3) in 8 bits: ``204 − 76 = 128`` of 255
GYM_INTENSITY = 128 / 255
#: gym's torque-arrow ring where it crosses the hanging rod: centre ``(x, y)`` (world
#: units, ``y`` below the pivot), radius and width of an opaque black circular band.
#: Fitted to the reference frames (``tests/data/gym_pendulum_frames.npz``) through the
#: reference's own pipeline (point-sampled 1000 × 1000 screen, crop, PIL tent): mean
#: absolute difference 0.00023, max 0.012 over the 701 frames (``benchmarks/gym_frames.py``).
GYM_ARROW_RING: tuple[float, float, float, float] = (0.0259, 0.0392, 0.4446, 0.0332)


def _coverage(sd: Tensor, filt: str, scale: float = 1.0) -> Tensor:
    """In place, ``scale ×`` a pixel's covered fraction from the signed distance ``sd``
    (pixels, negative inside) of its centre to a shape's edge: the ``box`` ramp
    ``clamp(½ − sd, 0, 1)`` or the ``tent`` profile (see :func:`render_pendulum`)."""
    if filt == "box":
        return sd.mul_(-scale).add_(0.5 * scale).clamp_(0.0, scale)
    x = sd.clamp_(-1.0, 1.0)
    return torch.where(x < 0, 1 - 0.5 * (1 + x) ** 2, 0.5 * (1 - x) ** 2).mul_(scale)


def _tent_matrix(size: int, k: int, dtype: torch.dtype, device: torch.device) -> Tensor:
    """``(size, k·size)`` rows of a tent of half-width one output pixel (``k`` input
    pixels) over the input pixel centres, each row normalised to 1 (PIL renormalises
    its resampling weights at the borders the same way)."""
    n = (torch.arange(size * k, dtype=dtype, device=device) + 0.5) / k
    j = torch.arange(size, dtype=dtype, device=device) + 0.5
    w = (1 - (n.view(1, -1) - j.view(-1, 1)).abs()).clamp_(min=0)
    return w / w.sum(1, keepdim=True)


def render_pendulum(
    theta: Tensor | float,
    size: int = 28,
    *,
    length: float = 1.0,
    width: float = 0.2,
    intensity: float = GYM_INTENSITY,
    axle_radius: float = 0.05,
    x_range: tuple[float, float] = GYM_CROP_X,
    y_range: tuple[float, float] = GYM_CROP_Y,
    supersample: int = 4,
    filter: str = "tent",
    arrow: bool = True,
    ring: tuple[float, float, float, float] = GYM_ARROW_RING,
    chunk: int | None = None,
) -> Tensor:
    """Gym Pendulum-v0 frames (reference preprocessing), ``(...,) -> (..., size, size)``:
    geometry, world → pixel map, anti-aliasing, the arrow band and how faithful the
    defaults are: see the module's docstring.

    Args:
        theta: angles (radians), any shape; a float tensor sets the dtype (else the
            default dtype); the device follows ``theta``.
        size: frame side in pixels; ``supersample``: ``k``, sub-pixels per side.
        length, width: the rod (pivot to its tip cap's centre; capsule diameter), and
            ``axle_radius`` the axle disc's (0: none), world units.
        intensity: a fully covered rod pixel (``R − G``: ``(204 − 76)/255``).
        x_range, y_range: the window ``(x0, x1)``, ``(y0, y1)``, world units, ``+x`` to
            the right, ``y`` **below** the pivot.
        filter: ``"box"`` (pixel coverage) or ``"tent"`` (bilinear down-sampling).
        arrow: draw the torque arrow's band across the rod.
        ring: the band's ``(cx, cy, radius, width)``, world units.
        chunk: frames per batch (default: see **Speed** in the module's docstring).

    Returns ``(..., size, size)``, values in ``[0, intensity]``.
    """
    if filter not in _FILTERS or supersample < 1 or size < 1:
        raise ValueError(f"filter must be in {_FILTERS}, size and supersample >= 1")
    theta = torch.as_tensor(theta)
    theta = theta.to(theta.dtype if theta.is_floating_point() else torch.get_default_dtype())
    dtype, k, fine = theta.dtype, supersample, size * supersample
    xs, ys, h = _grid(fine, x_range, y_range, dtype, theta.device)
    ramp = filter if k == 1 else "box"  # with k > 1 the tent comes when shrinking by k
    axle = _axle(xs, ys, h, axle_radius, ramp, intensity)
    band = 1 - _coverage(_ring_distance(xs, ys, ring).div_(h), ramp) if arrow else None
    tent = _tent_matrix(size, k, dtype, theta.device) if k > 1 and filter == "tent" else None
    chunk = chunk or max(16, 32768 // (fine * fine))
    flat = theta.reshape(-1)
    frames = torch.empty(flat.numel(), size, size, dtype=dtype, device=theta.device)
    for start in range(0, flat.numel(), chunk):
        th = flat[start : start + chunk].view(-1, 1, 1)
        img = _coverage(_rod_distance(th, xs, ys, length, width / 2).div_(h), ramp, intensity)
        img = img if band is None else img.mul_(band)
        if axle is not None:
            (rows, cols), disc = axle
            img[..., rows, cols] = (img[..., rows, cols] - disc).clamp_(min=0.0)
        if k > 1 and tent is None:
            img = img.view(-1, size, k, size, k).mean((2, 4))
        frames[start : start + chunk] = img if tent is None else tent @ img @ tent.T
    return frames.reshape(*theta.shape, size, size)


def _grid(
    fine: int, x_range: tuple[float, float], y_range: tuple[float, float], dtype, device
) -> tuple[Tensor, Tensor, float]:
    """Pixel-centre coordinates ``xs (1, 1, fine)``, ``ys (1, fine, 1)`` of the window and
    the pixel scale ``h = √(hx·hy)``."""
    (x0, x1), (y0, y1) = x_range, y_range
    hx, hy = (x1 - x0) / fine, (y1 - y0) / fine
    xs = x0 + (torch.arange(fine, dtype=dtype, device=device) + 0.5) * hx
    ys = y0 + (torch.arange(fine, dtype=dtype, device=device) + 0.5) * hy
    return xs.view(1, 1, fine), ys.view(1, fine, 1), math.sqrt(hx * hy)


def _axle(
    xs: Tensor, ys: Tensor, h: float, radius: float, ramp: str, intensity: float
) -> tuple[tuple[slice, slice], Tensor] | None:
    """The axle disc's coverage on the few pixels within ``radius + 2 px`` of the pivot:
    ``((rows, cols), disc)``, or ``None`` (no axle, or none of it in the window)."""
    if radius <= 0:
        return None
    reach = radius + 2 * h
    rows = (ys.view(-1).abs() <= reach).nonzero().view(-1)
    cols = (xs.view(-1).abs() <= reach).nonzero().view(-1)
    if not (rows.numel() and cols.numel()):
        return None
    rows = slice(int(rows[0]), int(rows[-1]) + 1)
    cols = slice(int(cols[0]), int(cols[-1]) + 1)
    d = torch.hypot(xs[..., cols], ys[:, rows])
    return (rows, cols), _coverage(d.sub_(radius).div_(h), ramp, intensity)


def _ring_distance(xs: Tensor, ys: Tensor, ring: tuple[float, float, float, float]) -> Tensor:
    """Signed distance to the arrow's band ``ring = (cx, cy, radius, width)``:
    ``| |(x, y) − (cx, cy)| − radius | − width/2``."""
    cx, cy, radius, band_width = ring
    return torch.hypot(xs - cx, ys - cy).sub_(radius).abs_().sub_(band_width / 2)


def _rod_distance(th: Tensor, xs: Tensor, ys: Tensor, length: float, r: float) -> Tensor:
    """Signed distance ``(n, fine, fine)`` to the capsule of radius ``r`` around the
    segment from the pivot to ``length·(sin θ, cos θ)``, for angles ``th (n, 1, 1)``."""
    s, c = torch.sin(th), torch.cos(th)
    along = xs * s + ys * c
    across = xs * c - ys * s
    excess = along.sub_(length / 2).abs_().sub_(length / 2).clamp_(min=0.0)
    return torch.hypot(across, excess).sub_(r)


def frame_strip(
    frames: Tensor, scale: int = 4, gap: int = 1, gap_value: int = 128, vmax: float | None = None
) -> Tensor:
    """Tile frames ``(n, H, W)`` left to right into one ``uint8`` image.

    Each frame is mapped linearly from ``[0, vmax]`` (default its overall maximum) to
    ``[0, 255]``, upscaled ``scale ×`` (nearest) and separated by ``gap`` pixels of
    ``gap_value``. Returns ``(H·scale, n·W·scale + (n − 1)·gap)``.
    """
    frames = frames.detach().cpu().to(torch.float64)
    vmax = float(frames.max()) if vmax is None else vmax
    img = (frames / max(vmax, 1e-12)).clamp(0, 1).mul(255).round().to(torch.uint8)
    img = img.repeat_interleave(scale, dim=-2).repeat_interleave(scale, dim=-1)
    n, hh, ww = img.shape
    sep = torch.full((n, hh, gap), gap_value, dtype=torch.uint8)
    tiled = torch.cat([img, sep], dim=2).permute(1, 0, 2).reshape(hh, -1)
    return tiled[:, : n * (ww + gap) - gap]
