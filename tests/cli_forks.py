"""``python -m hnn_pl`` without paying for the interpreter and its imports each time.

Started once per test module (client: ``tests/forks.py``): imports what the command line
imports (torch, Lightning, the package), then reads one JSON request per line from
stdin — ``{"argv", "cwd", "env", "unset", "stdout", "stderr"}`` and optionally
``"script"`` — and runs each in a forked child exactly as ``python -m hnn_pl *argv``
(or ``python SCRIPT *argv``) would in ``cwd``: the child's environment, ``sys.argv[0]``
the package's ``__main__.py`` (or the script), ``sys.path[0]`` the working directory
(the script's directory), so a module a checkpoint names is importable there, as it
would be; its stdout/stderr written to the named files, its exit status the way the
interpreter sets it. The parent answers each request with ``{"code": status}``.
Nothing torch computes runs in the parent before a fork.
"""

from __future__ import annotations

import json
import os
import runpy
import sys
import traceback

import hnn_pl
import hnn_pl.commands.cli  # noqa: F401  (Lightning, jsonargparse: the slow imports)
from hnn_pl.commands.main import main

MAIN = os.path.join(os.path.dirname(hnn_pl.__file__), "__main__.py")

#: configs the parent resolves before serving: a child's first parse of a config then
#: reads the signatures of the trainer and of these model and data classes from
#: jsonargparse's caches instead of inspecting them (0.5 s a command cold, 0.2 s warm)
WARM = ("spring.yaml", "real_pendulum_positions_dissipative.yaml", "chain2_100_mechanical_hnn.yaml")


def _exit_status(error: SystemExit) -> int:
    """The interpreter's rule: ``None`` → 0, an int → itself, anything else printed → 1."""
    if error.code is None:
        return 0
    if isinstance(error.code, int):
        return error.code
    print(error.code, file=sys.stderr)
    return 1


def _child(request: dict) -> int:
    os.chdir(request["cwd"])
    os.environ.update(request["env"])
    for name in request["unset"]:
        os.environ.pop(name, None)
    for fd, path in ((1, request["stdout"]), (2, request["stderr"])):
        os.dup2(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644), fd)
    script = request.get("script")
    sys.argv = [script or MAIN, *request["argv"]]
    sys.path[0] = os.path.dirname(os.path.abspath(script)) if script else os.getcwd()
    try:
        if script:
            runpy.run_path(script, run_name="__main__")
        else:
            main(request["argv"])
        code = 0
    except SystemExit as error:
        code = _exit_status(error)
    except BaseException:
        traceback.print_exc()
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    return code


def warm() -> None:
    """Resolve :data:`WARM` (``fit --config C --print_config``) with its output and its
    warnings discarded (leaving ``catch_warnings`` invalidates the once-only registries,
    so a child still prints a warning the parent saw)."""
    import contextlib
    import io
    import warnings

    for config in WARM:
        with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
            warnings.simplefilter("ignore")
            with contextlib.suppress(SystemExit):
                main(["fit", "--config", config, "--print_config"])


def serve() -> None:
    warm()
    for line in sys.stdin:
        request = json.loads(line)
        pid = os.fork()
        if pid == 0:
            code = 1
            try:
                code = _child(request)
            finally:
                os._exit(code)
        _, status = os.waitpid(pid, 0)
        print(json.dumps({"code": os.waitstatus_to_exitcode(status)}), flush=True)


if __name__ == "__main__":
    serve()
