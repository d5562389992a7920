"""Shared helpers: timing, Markdown tables, the machine table, the report's markers, the CLI."""

from __future__ import annotations

import argparse
import contextlib
import datetime
import importlib.metadata
import os
import platform
import re
import time
from pathlib import Path

import torch
from torch.utils.benchmark import Timer

REPORT = Path(__file__).resolve().parents[1] / "BENCHMARKS.md"


def measure(fn, min_run_time: float = 0.25, threads: int = 1, once_above: float = 0.5):
    """Median seconds per ``fn()`` call and the number of timed calls.

    One warm-up call; if it took ``once_above`` seconds or more it is the only timing,
    otherwise ``Timer(...).blocked_autorange(min_run_time)`` with ``threads`` torch threads.
    """
    with threads_ctx(threads):
        t0 = time.perf_counter()
        fn()
        first = time.perf_counter() - t0
    if first >= once_above:
        return first, 1
    m = Timer("fn()", globals={"fn": fn}, num_threads=threads).blocked_autorange(
        min_run_time=min_run_time
    )
    return m.median, len(m.times) * m.number_per_run


@contextlib.contextmanager
def threads_ctx(n: int):
    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def table(header: str, rows: list[list]) -> str:
    """A Markdown table; ``header``: the column names separated by `` | ``."""
    lines = [f"| {header} |", "|" + "---|" * len(header.split(" | "))]
    return "\n".join(lines + ["| " + " | ".join(str(c) for c in r) + " |" for r in rows])


def ms(seconds: float) -> str:
    """Milliseconds, 3 significant digits (a plain number)."""
    x = 1e3 * seconds
    return f"{x:.3g}" if x < 100 else f"{x:.0f}"


def machine_table() -> str:
    cpu = platform.processor() or "unknown"
    with contextlib.suppress(OSError):
        lines = Path("/proc/cpuinfo").read_text().splitlines()
        cpu = next(
            (ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("model name")), cpu
        )
    versions = " / ".join(importlib.metadata.version(p) for p in ("lightning", "scipy", "numpy"))
    rows = [
        ["CPU", cpu],
        ["cores", f"{os.cpu_count()} logical, {len(os.sched_getaffinity(0))} usable"],
        ["torch", f"{torch.__version__} ({torch.backends.cpu.get_cpu_capability()} kernels)"],
        ["lightning / scipy / numpy", versions],
        ["python", platform.python_version()],
    ]
    return table(" | ", rows)


def write_section(path: Path, name: str, title: str, body: str) -> None:
    """Replace the text between ``<!-- begin name -->`` and ``<!-- end name -->`` in
    ``path``; append the markers under a ``## title`` heading if the file has none."""
    text = path.read_text() if path.exists() else "# hnn_pl benchmarks\n"
    block = f"<!-- begin {name} -->\n{body.strip()}\n<!-- end {name} -->"
    pattern = re.compile(rf"<!-- begin {name} -->.*?<!-- end {name} -->", re.S)
    if pattern.search(text):
        text = pattern.sub(lambda _: block, text, count=1)
    else:
        text = f"{text.rstrip()}\n\n## {title}\n\n{block}\n"
    path.write_text(text)


def main(topics: dict, default_out: Path | None) -> None:
    """``[--quick] [--out PATH] [--only NAME ...]``: run topics, print or write them."""
    parser = argparse.ArgumentParser(description="hnn_pl benchmarks (Markdown tables)")
    parser.add_argument("--quick", action="store_true", help="a smoke run (seconds)")
    parser.add_argument("--out", type=Path, default=default_out, help="report to update")
    parser.add_argument("--only", nargs="+", choices=list(topics), help="run only these")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.out:
        write_section(args.out, "machine", "Machine", machine_table())
    for name in args.only or topics:
        load0, t0 = os.getloadavg()[0], time.perf_counter()
        body = topics[name].run(args.quick)
        date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        body = (  # the date, duration and load average above the tables
            f"*{date}{', `--quick`' if args.quick else ''}: {time.perf_counter() - t0:.0f} s, "
            f"1-minute load average {load0:.2f} → {os.getloadavg()[0]:.2f}.*\n\n{body}"
        )
        if args.out:
            write_section(args.out, name, topics[name].TITLE, body)
        print(f"## {topics[name].TITLE}\n\n{body}\n", flush=True)


def quiet_cli(config: str, seed: int, threads: int = 1, max_steps: int | None = None, extra=()):
    """A bundled config as ``fit`` runs it, minus logger, checkpoints, progress bar,
    callbacks and validation, built but not run: ``cli.trainer.fit(cli.model,
    cli.datamodule)`` trains it. ``extra``: more CLI arguments (overrides)."""
    from hnn_pl.commands.cli import cli_main, quiet_args

    args = [f"--config={config}", f"--seed_everything={seed}", f"--threads={threads}"]
    args += quiet_args()
    args += [f"--trainer.max_steps={max_steps}"] if max_steps else []
    return cli_main(args + list(extra), run=False, save_config=False)
