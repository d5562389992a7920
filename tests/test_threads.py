"""``--threads auto``: the cores not busy with other processes, seen at once."""

from __future__ import annotations

import os
import subprocess
import sys

from hnn_pl.safe_io import idle_cores, runnable_others

SPIN = "import sys; print('ready', flush=True)\nwhile True: pass"


def test_runnable_others_reads_proc_loadavg():
    """The fourth field of ``/proc/loadavg`` counts this process too; text that is not
    that file gives 0."""
    assert runnable_others("0.99 1.68 1.81 3/345 12345") == 2
    assert runnable_others("0.00 0.00 0.00 1/88 7") == 0
    assert runnable_others("") == 0 and runnable_others("a b c d e") == 0


def test_a_process_started_just_now_takes_a_core():
    """A busy process a moment old (nothing in the 1-minute load average yet) leaves one
    core fewer: two fits started together no longer each take every core."""
    cores = len(os.sched_getaffinity(0))
    spinner = subprocess.Popen([sys.executable, "-c", SPIN], stdout=subprocess.PIPE, text=True)
    try:
        assert spinner.stdout.readline().strip() == "ready"
        assert runnable_others() >= 1
        assert idle_cores() <= max(1, cores - 1)
    finally:
        spinner.kill()
        spinner.wait()
