"""The README is executable documentation: its Quickstart, Commands and From-Python
blocks run in order in a fresh directory, as a new user pastes them, and any failing
line fails the test."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SECTIONS = ("Quickstart", "Commands", "From Python")

#: README lines that train for minutes as written: the few steps they get here
SHORTER = {"hnn-pl fit --model HNN ": "--trainer.max_steps 5"}

#: ``make test`` is this suite (it cannot run itself); ``tensorboard`` serves until
#: Ctrl-C: it passes once it says where it serves the logs
PRELUDE = r"""
set -eo pipefail
source() { { set +x; } 2>/dev/null; builtin source "$@"; set -x; }
make() {
  { set +x; } 2>/dev/null
  if [ "${1:-}" = test ]; then echo "make test: the suite running this"; set -x; return 0; fi
  command make -o .venv/.installed "$@"
  set -x
}
tensorboard() {
  { set +x; } 2>/dev/null
  command tensorboard "$@" > tensorboard.log 2>&1 &
  local pid=$!
  for _ in $(seq 120); do
    if grep -q "http://" tensorboard.log; then kill $pid; wait $pid || true; set -x; return 0; fi
    if ! kill -0 $pid 2>/dev/null; then cat tensorboard.log >&2; return 1; fi
    sleep 0.5
  done
  kill $pid; cat tensorboard.log >&2; return 1
}
PS4="+ \$(date +%T) "
set -x
"""


def readme_blocks(sections: tuple[str, ...] = SECTIONS) -> list[tuple[str, str]]:
    """``(language, code)`` of the fenced blocks in the README's ``## <section>``s, in
    order."""
    text = (ROOT / "README.md").read_text()
    parts = re.split(r"^## ", text, flags=re.M)
    wanted = [p for p in parts if p.split("\n", 1)[0].strip() in sections]
    assert len(wanted) == len(sections), "a README section is missing"
    return [
        (lang, code)
        for part in wanted
        for lang, code in re.findall(r"^```(\w+)\n(.*?)^```", part, flags=re.M | re.S)
    ]


def _shortened(line: str) -> str:
    for start, extra in SHORTER.items():
        if line.startswith(start):
            command, _, comment = line.partition("  #")
            return f"{command.rstrip()} {extra}" + (f"  #{comment}" if comment else "")
    return line


def test_the_blocks_are_the_ones_a_reader_follows():
    blocks = readme_blocks()
    assert [lang for lang, _ in blocks] == ["bash", "bash", "bash", "python"]
    assert blocks[0][1].startswith("make fit")
    lines = [line for _, code in blocks for line in code.splitlines()]
    assert any(line.startswith(tuple(SHORTER)) for line in lines)
    # one convention: the activated venv, never .venv/bin/ or python -m
    for line in lines:
        assert ".venv/bin/" not in line.replace("source .venv/bin/activate", ""), line
        assert "python -m hnn_pl" not in line, line


@pytest.mark.slow
@pytest.mark.skipif(
    not (Path(sys.prefix) / "bin" / "activate").is_file(), reason="needs a venv as .venv"
)
def test_readme_quickstart_commands_and_python_run_in_a_fresh_directory(tmp_path):
    """``make fit`` with this checkout's Makefile and this venv as ``.venv``
    (``-o .venv/.installed``: never reinstalled from the temporary directory)."""
    for name in ("Makefile", "pyproject.toml"):
        (tmp_path / name).symlink_to(ROOT / name)
    (tmp_path / ".venv").symlink_to(sys.prefix)
    env = {**os.environ, "HNN_PL_TRACEBACK": "1"}
    sessions: list[tuple[str, str]] = []  # consecutive bash blocks: one shell, as a reader's
    for lang, code in readme_blocks():
        if lang == "bash" and sessions and sessions[-1][0] == "bash":
            sessions[-1] = ("bash", sessions[-1][1] + code)
        else:
            sessions.append((lang, code))
    for lang, code in sessions:
        if lang == "bash":
            script = PRELUDE + "\n".join(_shortened(line) for line in code.splitlines())
            command = ["bash", "-c", script]
        else:
            command = [str(tmp_path / ".venv" / "bin" / "python"), "-c", code]
        done = subprocess.run(
            command, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900
        )
        print(done.stderr if lang == "bash" else done.stdout)  # the timed trace, with -s
        assert done.returncode == 0, f"{code}\n--- stdout\n{done.stdout}\n--- stderr\n{done.stderr}"
    run = tmp_path / "lightning_logs" / "spring_fast_hnn"
    assert sorted(p.name for p in run.iterdir()) == ["version_0"]
    assert {"rollouts.pt", "bump.png", "config_test.yaml"} <= {p.name for p in run.glob("*/*")}
    assert (tmp_path / "lightning_logs" / "mass_spring_hnn" / "version_0").is_dir()
