"""The README and the guide are executable documentation: every fenced block of the
README and of each guide page runs, in order, in a fresh directory, as a reader pastes
it (``bash`` blocks in a shell, ``python`` blocks in the venv's interpreter, ``yaml``
blocks saved under the file name their first line gives), and any failing line fails the
test. ``text`` blocks are output, not input."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent
RUNNABLE = ("bash", "python", "yaml")

#: lines that train for minutes as written: the few steps they get here (a line's
#: environment assignments, ``PYTHONPATH=… hnn-pl fit``, are kept)
SHORTER = (
    (re.compile(r"^(\w+=\S+ )*hnn-pl fit (?!.*help)"), "--trainer.max_steps 5"),
    (re.compile(r"^hnn-pl reproduce "), "--max-steps 3"),
)

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


def guide_pages() -> list[Path]:
    """The guide's pages, in the order of ``mkdocs.yml``'s nav."""
    nav = yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"]
    (guide,) = [entry["Guide"] for entry in nav if "Guide" in entry]
    return [ROOT / "docs" / next(iter(page.values())) for page in guide]


def blocks(path: Path) -> list[tuple[str, str]]:
    """``(language, code)`` of every fenced block of a Markdown file, in order."""
    text = path.read_text()
    return re.findall(r"^```(\w*)\n(.*?)^```", text, flags=re.M | re.S)


def yaml_name(code: str) -> str:
    """The file a ``yaml`` block is saved as: its first line, ``# NAME.yaml: …``."""
    found = re.match(r"# ([\w.-]+\.yaml)\b", code)
    assert found, f"a yaml block's first line names its file (# NAME.yaml: …):\n{code}"
    return found.group(1)


def _shortened(line: str) -> str:
    for pattern, extra in SHORTER:
        if pattern.match(line):
            command, _, comment = line.partition("  #")
            return f"{command.rstrip()} {extra}" + (f"  #{comment}" if comment else "")
    return line


def run_blocks(path: Path, cwd: Path) -> None:
    """Run ``path``'s blocks in ``cwd`` in order; consecutive ``bash`` blocks share a
    shell, as a reader's."""
    env = {**os.environ, "HNN_PL_TRACEBACK": "1"}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    sessions: list[tuple[str, str]] = []
    for lang, code in blocks(path):
        if lang == "yaml":
            (cwd / yaml_name(code)).write_text(code)
        elif lang == "bash" and sessions and sessions[-1][0] == "bash":
            sessions[-1] = ("bash", sessions[-1][1] + code)
        elif lang in RUNNABLE:
            sessions.append((lang, code))
    for lang, code in sessions:
        if lang == "bash":
            script = PRELUDE + "\n".join(_shortened(line) for line in code.splitlines())
            command = ["bash", "-c", script]
        else:
            command = [sys.executable, "-c", code]
        done = subprocess.run(
            command, cwd=cwd, env=env, capture_output=True, text=True, timeout=900
        )
        print(done.stderr if lang == "bash" else done.stdout)  # the timed trace, with -s
        assert done.returncode == 0, f"{code}\n--- stdout\n{done.stdout}\n--- stderr\n{done.stderr}"


def test_the_readme_blocks_are_the_ones_a_reader_follows():
    found = blocks(ROOT / "README.md")
    assert [lang for lang, _ in found] == [
        "bash",
        "bash",
        "python",
        "python",
        "yaml",
        "bash",
        "bash",
    ]
    assert found[0][1].startswith("make fit")
    lines = [line for _, code in found for line in code.splitlines()]
    assert any(_shortened(line) != line for line in lines)
    # one convention: the activated venv, never .venv/bin/ or python -m
    for line in lines:
        assert ".venv/bin/" not in line.replace("source .venv/bin/activate", ""), line
        assert "python -m hnn_pl" not in line, line


def test_every_guide_block_is_runnable_input_or_output():
    for page in [ROOT / "README.md", *guide_pages()]:
        for lang, code in blocks(page):
            assert lang in (*RUNNABLE, "text"), f"{page.name}: a ```{lang} block"
            if lang == "yaml":
                yaml.safe_load(code)
                yaml_name(code)


@pytest.mark.slow
@pytest.mark.skipif(
    not (Path(sys.prefix) / "bin" / "activate").is_file(), reason="needs a venv as .venv"
)
def test_readme_runs_in_a_fresh_directory(tmp_path):
    """``make fit`` with this checkout's Makefile and this venv as ``.venv``
    (``-o .venv/.installed``: never reinstalled from the temporary directory), then the
    tour, the recording and the reproduction as written."""
    for name in ("Makefile", "pyproject.toml"):
        (tmp_path / name).symlink_to(ROOT / name)
    (tmp_path / ".venv").symlink_to(sys.prefix)
    run_blocks(ROOT / "README.md", tmp_path)
    run = tmp_path / "lightning_logs" / "spring_fast_hnn"
    assert sorted(p.name for p in run.iterdir()) == ["version_0"]
    assert {"rollouts.pt", "bump.png", "config_test.yaml"} <= {p.name for p in run.glob("*/*")}
    assert (tmp_path / "lightning_logs" / "springs_hnn" / "version_0").is_dir()
    assert (tmp_path / "my_results" / "RESULTS.json").is_file()
