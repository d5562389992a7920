"""The client of ``tests/cli_forks.py``: commands and scripts run in forked children of
one interpreter that imported the package once (each run still its own process: its
exit status, its output, its working directory and environment)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


class Forks:
    """One ``tests/cli_forks.py`` interpreter. ``log``: a file that receives what the
    interpreter itself prints while it imports and warms up (else the caller's stderr)."""

    def __init__(self, log: Path | None = None, env: dict | None = None) -> None:
        env = {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}
        self._log = None if log is None else open(log, "w")  # noqa: SIM115
        self.proc = subprocess.Popen(
            [sys.executable, str(ROOT / "tests" / "cli_forks.py")],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=self._log,
            env=env,
            text=True,
        )

    def run(
        self,
        argv: list[str],
        cwd: Path,
        env: dict,
        unset: list[str],
        out: Path,
        script: Path | None = None,
    ) -> tuple[int, str]:
        """``python -m hnn_pl *argv`` (or ``python SCRIPT *argv``) in ``cwd`` with ``env``
        added and ``unset`` removed; its stdout and stderr go to ``out/stdout`` and
        ``out/stderr``. Its exit status and stderr."""
        request = {"argv": argv, "cwd": str(cwd), "env": env, "unset": unset}
        request |= {"stdout": str(out / "stdout"), "stderr": str(out / "stderr")}
        if script is not None:
            request["script"] = str(script)
        self.proc.stdin.write(json.dumps(request) + "\n")
        self.proc.stdin.flush()
        code = json.loads(self.proc.stdout.readline())["code"]
        return code, (out / "stderr").read_text()

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=60)
        if self._log is not None:
            self._log.close()
