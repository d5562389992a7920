"""``SimulatedData`` generation into an empty cache, loading on a cache hit, and reading a
large recording."""

from __future__ import annotations

import functools
import json
import math
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import main, measure, table

from hnn_pl.data import SimulatedData
from hnn_pl.systems import MassSpring, Pendulum, ThreeBody, TwoBody

TITLE = "Data generation"
NBODY = {"noise_std": 0.0, "test_fraction": 0.2, "test_first": True}
TASKS = (  # the bundled configs' parameters: system, trajectories, t_end, points per trajectory
    ("mass-spring", MassSpring, 50, 3, 30),
    ("pendulum", Pendulum, 50, 3, 45),
    ("two-body", TwoBody, 1000, 20, 50),
    ("three-body", ThreeBody, 5000, 5, 20),
)


def run(quick: bool) -> str:
    rows, repeats = [], 1 if quick else 3
    for name, system, k, t_end, points in TASKS[:2] if quick else TASKS:
        kwargs = dict(n_trajectories=k, t_span=(0, t_end), n_points=points)
        make = functools.partial(SimulatedData, system(), **kwargs, **(NBODY if k > 50 else {}))
        gen = []
        for _ in range(repeats):
            with tempfile.TemporaryDirectory() as cache:
                t0 = time.perf_counter()
                make(cache_dir=cache).prepare_data()
                gen.append(time.perf_counter() - t0)
        with tempfile.TemporaryDirectory() as cache:
            (dm := make(cache_dir=cache)).setup()
            load, n = measure(lambda cache=cache, make=make: make(cache_dir=cache).setup(), 0.2)
            size = sum(p.stat().st_size for p in Path(cache).iterdir()) / 1e6
        n_rows = len(dm.x_train) + len(dm.x_test)
        gen = f"{statistics.median(gen):.3f}"
        rows.append([f"{name} ({k} × {points})", n_rows, gen, f"{1e3 * load:.2f}", f"{size:.2f}"])
    return (
        "`SimulatedData(...).prepare_data()` into an empty temporary cache (sampling, float64 "
        "ground truth: closed form for the spring, else dopri5 at rtol = atol = 1e-10; "
        f"split, `torch.save`), median of {repeats} run(s), 1 thread; cache hit: "
        "`SimulatedData(...).setup()` on the filled cache (`torch.load`, cast to float32), "
        "median of `blocked_autorange`.\n\n"
        + table("task | rows | generate (s) | cache hit (ms) | cache file (MB)", rows)
        + "\n\n"
        + recording_read(quick)
    )


#: one ``load_recording`` in a fresh process (warmed on a small file first): seconds and
#: the growth of the resident set over the call (``ru_maxrss`` after − RSS before), or the
#: traced peak (``tracemalloc``, which slows numpy's parsing about sixfold: not timed)
READ_ONCE = """
import json, os, resource, sys, time, tracemalloc
from hnn_pl.data import load_recording
path, small, trace = sys.argv[1], sys.argv[2], sys.argv[3] == "trace"
load_recording(small, "float32")
page = os.sysconf("SC_PAGE_SIZE")
rss = int(open("/proc/self/statm").read().split()[1]) * page
if trace:
    tracemalloc.start()
t0 = time.perf_counter()
load_recording(path, "float32")
seconds = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - rss
if trace:
    peak = tracemalloc.get_traced_memory()[1]
print(json.dumps({"seconds": seconds, "peak": peak}))
"""


def _write_recording(path: Path, m: int, n: int, kind: str = "plain") -> None:
    """``m`` trajectories of ``n`` samples as ``trajectory,time,q1,p1`` lines (times to
    1e-6, states to 1e-8: 36 bytes a row); ``kind``: ``"notes"`` a ``#`` line and a
    blank one between trajectories, ``"float ids"`` ids written ``7.0``."""
    g = np.random.default_rng(0)
    t = np.cumsum(0.05 + 0.1 * g.random(n))
    with path.open("w") as f:
        f.write("# a recording for the benchmark\ntrajectory,time,q1,p1\n")
        for i in range(m):
            if kind == "notes":
                f.write(f"# trajectory {i}\n\n")
            q, p = g.standard_normal((2, n))
            ident = f"{i}.0" if kind == "float ids" else str(i)
            f.write("".join(f"{ident},{a:.6f},{b:.8f},{c:.8f}\n" for a, b, c in zip(t, q, p)))


READERS = {
    "plain": "plain (`loadtxt`)",
    "notes": "a `#` line and a blank one per trajectory (`loadtxt`)",
    "float ids": "ids written `7.0` (line reader)",
}


def _read_once(path: Path, small: Path, trace: bool) -> dict:
    argv = [sys.executable, "-c", READ_ONCE, str(path), str(small), "trace" if trace else "-"]
    out = subprocess.run(argv, check=True, capture_output=True, text=True)
    return json.loads(out.stdout)


def recording_read(quick: bool) -> str:
    """``load_recording`` of a CSV of ``10⁶`` rows, float32 served: time and peak memory
    in a fresh process, for files ``numpy.loadtxt`` parses (with and without comment
    lines) and one the line reader reads (float-notation ids); ``quick``: ``10⁵`` rows,
    plain, untraced."""
    m, n = (100, 1000) if quick else (1000, 1000)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        small = Path(tmp) / "small.csv"
        _write_recording(small, 2, 10)
        for kind in ("plain",) if quick else ("plain", "notes", "float ids"):
            path = Path(tmp) / "rec.csv"
            _write_recording(path, m, n, kind)
            size = path.stat().st_size
            timed = _read_once(path, small, False)
            traced = {"peak": math.nan} if quick else _read_once(path, small, True)
            rows.append(
                [
                    READERS[kind],
                    f"{m * n:,}",
                    f"{size / 1e6:.1f}",
                    f"{timed['seconds']:.2f}",
                    f"{timed['peak'] / 1e6:.0f} ({timed['peak'] / size:.1f}×)",
                    f"{traced['peak'] / 1e6:.0f}",
                ]
            )
    return (
        '`load_recording(path, "float32")` of a CSV recording (`trajectory,time,q1,p1`, '
        f"{m} trajectories × {n} samples), read and checked (ids, times, float32 fit), once in "
        "a fresh process warmed on a small file, 1 thread. Memory: the growth of the resident "
        "set over the call (`ru_maxrss` after − RSS before) and, in a second process, "
        "`tracemalloc`'s peak. The sample lines are parsed by `numpy.loadtxt`; the line reader "
        "(regular expressions, Python's `int`, `float`, `Decimal`) reads only what `loadtxt` "
        "refuses: "
        "float-notation ids, or a fault it then names.\n\n"
        + table(
            "file | rows | size (MB) | read + check (s) | peak RSS growth (MB) | traced peak (MB)",
            rows,
        )
    )


if __name__ == "__main__":
    main({"data": sys.modules[__name__]}, None)
