"""Files that are data, written whole, within the machine's means.

- :func:`load_checkpoint`: a checkpoint read as tensors and plain data only
  (``weights_only``); an empty, truncated, foreign or code-carrying file is one
  ``ValueError`` line naming the file, never torch's advice to load it unsafely nor
  the warnings torch gives while reading bytes that turn out not to be a checkpoint.
- :func:`torch_load`: ``torch.load`` of plain data, silent when it fails.
- :func:`write_atomic`, :func:`save_atomic`, :func:`atomic_checkpoint_io`: a file is
  written to a temporary name beside it and renamed into place, so a failure (a full
  disk, Ctrl-C) leaves the previous file and no partial one; a full disk is
  ``OSError("no space left on <directory>")``.
- :func:`check_model_class`: refuse a checkpoint of another model class (the model,
  the CLI and ``bump`` use it), comparing names without importing any;
  :func:`check_finite_weights` (every :func:`load_checkpoint` runs it),
  :func:`check_same_system`, :func:`check_state_shapes`: weights that are not finite,
  trained on another system, or of another shape, each refused in one line.
- :func:`checkpoint_init_args`, :func:`refuse_changed_options`: a run from a checkpoint
  takes the options it was trained with, and refuses one given otherwise.
- :func:`require_memory`: refuse work whose estimated memory exceeds the machine's;
  :func:`idle_cores`: the cores not busy with other processes.
"""

from __future__ import annotations

import errno
import io
import os
import pickle
import sys
import warnings
from pathlib import Path
from typing import Any

import torch


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """The dict in the checkpoint at ``path``, loaded with ``weights_only=True`` on CPU.

    Raises:
        ValueError: one line naming the file: missing, a directory, empty, truncated,
            not a torch file, holding more than weights, not a dict, or with weights
            that are not finite (:func:`check_finite_weights`).
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"checkpoint {path}: no such file")
    if path.is_dir():
        raise ValueError(f"checkpoint {path}: is a directory, not a checkpoint file")
    if path.stat().st_size == 0:
        raise ValueError(f"checkpoint {path}: the file is empty")
    try:
        ckpt = torch_load(path)
    except pickle.UnpicklingError as err:
        found = [line for line in str(err).splitlines() if "Unsupported global:" in line]
        if not found:
            raise ValueError(
                f"checkpoint {path}: cannot be read (not a torch checkpoint)"
            ) from None
        what = found[0].split("Unsupported global:")[1].split(" was not")[0].strip()
        raise ValueError(
            f"checkpoint {path}: refused, it holds more than weights and plain data "
            f"({what}); a checkpoint is never run as code"
        ) from None
    except RuntimeError as err:
        reason = "truncated or damaged" if "zip archive" in str(err) else "not a torch checkpoint"
        raise ValueError(f"checkpoint {path}: cannot be read ({reason})") from None
    except (EOFError, KeyError, ValueError, IndexError, TypeError, AttributeError):
        raise ValueError(f"checkpoint {path}: cannot be read (not a torch checkpoint)") from None
    except OSError as err:  # torch reports a cut zip archive as EINVAL
        reason = "truncated or damaged" if err.errno == errno.EINVAL else err.strerror or err
        raise ValueError(f"checkpoint {path}: cannot be read ({reason})") from None
    if not isinstance(ckpt, dict):
        raise ValueError(f"checkpoint {path}: holds a {type(ckpt).__name__}, not a checkpoint")
    check_finite_weights(ckpt, f"checkpoint {path}")
    return ckpt


def torch_load(path: str | os.PathLike) -> Any:
    """``torch.load(path, weights_only=True, map_location="cpu")`` whose warnings are given
    only if the load succeeds: on bytes that are not a torch file (say, random bytes
    opening with a pickle PROTO opcode) torch warns before it fails, and the caller's
    one-line refusal is all a user should read."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        obj = torch.load(path, weights_only=True, map_location="cpu")
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return obj


def check_finite_weights(ckpt: dict[str, Any], where: str) -> None:
    """Refuse a checkpoint whose ``state_dict`` holds a floating tensor with a NaN or an
    infinity: ``ValueError`` naming ``where``, the first such tensor and its count (such
    weights would be tested to nan metrics, rolled out or bumped without a word)."""
    state = ckpt.get("state_dict")
    if not isinstance(state, dict):
        return
    for name, value in state.items():
        if not (torch.is_tensor(value) and value.is_floating_point()):
            continue
        bad = int((~torch.isfinite(value)).sum())
        if bad:
            raise ValueError(
                f"{where}: its weights are not finite ({name}: {bad} of {value.numel()} values "
                "are nan or inf); use a checkpoint of a run that did not diverge"
            )


def check_same_system(ckpt: dict[str, Any], datamodule: Any, where: str) -> None:
    """Refuse a checkpoint trained on another system than ``datamodule``'s: both
    DataModules' hyperparameters record ``system`` as ``{"class_path", "init_args"}``
    (:func:`~hnn_pl.systems.base.system_spec`); ``ValueError`` naming both. Nothing to
    compare (no system on either side, e.g. a recording without one) passes."""
    saved = (ckpt.get("datamodule_hyper_parameters") or {}).get("system")
    current = (getattr(datamodule, "hparams", None) or {}).get("system")
    if not (isinstance(saved, dict) and isinstance(current, dict)):
        return
    if _spec_key(saved) == _spec_key(current):
        return
    same_class = saved.get("class_path") == current.get("class_path")
    raise ValueError(
        f"{where} was trained on {_spec_name(saved, current if same_class else None)} but the "
        f"config's data is {_spec_name(current, saved if same_class else None)}: use the "
        "config the checkpoint was trained with"
    )


def _spec_key(spec: dict[str, Any]) -> str:
    import json

    return json.dumps(
        {"class_path": spec.get("class_path"), "init_args": spec.get("init_args") or {}},
        sort_keys=True,
        default=str,
    )


def _spec_name(spec: dict[str, Any], other: dict[str, Any] | None) -> str:
    """``class_path``, with the init_args that differ from ``other``'s (same class)."""
    name = str(spec.get("class_path"))
    if other is None:
        return name
    mine, theirs = spec.get("init_args") or {}, other.get("init_args") or {}
    diff = [
        f"{k}={mine.get(k)!r}"
        for k in sorted(set(mine) | set(theirs))
        if mine.get(k) != theirs.get(k)
    ]
    return f"{name}({', '.join(diff)})"


def check_state_shapes(saved: dict[str, Any], own: dict[str, Any], where: str) -> None:
    """Refuse a state dict ``saved`` whose names or shapes differ from a model's ``own``:
    one ``ValueError`` line naming the first difference (torch's is many lines)."""
    missing = [k for k in own if k not in saved]
    extra = [k for k in saved if k not in own]
    shapes = [
        k
        for k in own
        if k in saved and torch.is_tensor(saved[k]) and saved[k].shape != own[k].shape
    ]
    if not (missing or extra or shapes):
        return
    if shapes:
        k = shapes[0]
        what = f"{k} has shape {tuple(saved[k].shape)}, the config's model {tuple(own[k].shape)}"
    else:
        what = f"no {missing[0]}" if missing else f"an unknown {extra[0]}"
        what = f"it holds {what}"
    raise ValueError(
        f"{where} does not fit the config's model ({what}): use the config it was trained with"
    )


def loaded_class(path: str) -> type | None:
    """The class at the dotted ``path`` if its module is already imported, else
    ``None``. Never imports: a name read from a file must not run code."""
    module, _, name = path.rpartition(".")
    obj = sys.modules.get(module)
    for part in name.split("."):
        obj = getattr(obj, part, None) if obj is not None else None
    return obj if isinstance(obj, type) else None


def class_name(cls: type) -> str:
    """``module.QualName`` of ``cls``."""
    return f"{cls.__module__}.{cls.__qualname__}"


def check_model_class(ckpt: dict[str, Any], expected: str | type, where: str) -> None:
    """Refuse a checkpoint whose saved model class (``hnn_pl_model_class``, or
    LightningCLI's ``hyper_parameters["_class_path"]``) is not ``expected`` (a class or
    a dotted path): ``ValueError`` naming ``where`` (e.g. ``"checkpoint C"``). Compared
    as names: a saved name counts as the class only if spelled like it or naming the
    same class in a module already imported."""
    cls = expected if isinstance(expected, type) else loaded_class(expected)
    path = expected if isinstance(expected, str) else class_name(expected)
    names = {path} | ({class_name(cls)} if cls else set())
    hparams = ckpt.get("hyper_parameters") or {}
    for saved in (ckpt.get("hnn_pl_model_class"), hparams.get("_class_path")):
        if saved is None:
            continue
        if not (
            isinstance(saved, str) and (saved in names or (cls and loaded_class(saved) is cls))
        ):
            raise ValueError(
                f"{where} holds a {saved} but the config builds a {path}: "
                "use the config the checkpoint was trained with"
            )


def _plain(value: Any) -> bool:
    if isinstance(value, (list, tuple)):
        return all(_plain(v) for v in value)
    return value is None or isinstance(value, (bool, int, float, str))


#: model options a checkpoint never restores: linked from the data, or about the run
#: itself (``reinit_states``: what a resumed fit does with learned states)
NOT_RESTORED = ("input_dim", "reinit_states")
#: model options whose checkpoint value must be the config's: restoring it silently
#: would make the model refuse the config's data
MUST_MATCH = ("objective",)


def checkpoint_init_args(
    ckpt: dict[str, Any], init_args: Any, given: set[str] | frozenset[str] = frozenset()
) -> dict[str, Any]:
    """The checkpoint's hyperparameters that restore the config's ``init_args``: keys the
    config already has with a plain value, given plain values (never a class path),
    except :data:`NOT_RESTORED` and the options ``given`` on the command line (which
    :func:`refuse_changed_options` has compared)."""
    hparams = ckpt.get("hyper_parameters") or {}
    current = vars(init_args) if init_args is not None and hasattr(init_args, "__dict__") else {}
    return {
        k: v
        for k, v in hparams.items()
        if k in current
        and k not in NOT_RESTORED
        and k not in given
        and _plain(v)
        and _plain(current[k])
    }


def refuse_changed_options(
    ckpt: dict[str, Any], init_args: Any, given: set[str], where: str
) -> None:
    """A run from a checkpoint keeps the options it was trained with: a model option
    ``given`` on the command line with another value than the checkpoint's, or one of
    :data:`MUST_MATCH` that the config sets otherwise, is a one-line ``ValueError``
    naming both values (never silently replaced; :data:`NOT_RESTORED` excepted)."""
    hparams = ckpt.get("hyper_parameters") or {}
    current = vars(init_args) if init_args is not None and hasattr(init_args, "__dict__") else {}
    for k in [*sorted(given), *MUST_MATCH]:
        if k in NOT_RESTORED or k not in hparams or k not in current:
            continue
        saved, value = hparams[k], current[k]
        if not (_plain(saved) and _plain(value)) or _same(saved, value) or saved == "auto":
            continue  # "auto": a model saved before it saw data, which sets it
        if k in given:
            raise ValueError(
                f"--model.init_args.{k}={value}: {where} was trained with {k}={saved!r}, and "
                "a run from a checkpoint keeps the options it was trained with: remove the "
                "option, or fit anew without --ckpt_path"
            )
        raise ValueError(
            f"{where} was trained with {k}={saved!r} but the config sets {k}: {value!r}: use "
            "the config the checkpoint was trained with"
        )


def _same(a: Any, b: Any) -> bool:
    """Equal plain values, a list equal to a tuple of the same items."""
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return list(a) == list(b)
    return a == b


def no_space(path: str | os.PathLike) -> OSError:
    """The one-line error (errno ``ENOSPC``) of a full file system while writing ``path``."""
    err = OSError(f"no space left on {Path(path).parent}")
    err.errno = errno.ENOSPC
    return err


def write_atomic(path: str | os.PathLike, data: bytes | memoryview) -> None:
    """Write ``data`` to ``path`` whole: a temporary file beside it, then a rename.

    On any failure the temporary file is removed and ``path`` is as it was; a full
    file system raises :func:`no_space`.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as err:
        tmp.unlink(missing_ok=True)
        if isinstance(err, OSError) and err.errno in (errno.ENOSPC, errno.EDQUOT):
            raise no_space(path) from None
        raise


def save_atomic(obj: Any, path: str | os.PathLike) -> None:
    """``torch.save(obj, path)`` through :func:`write_atomic`."""
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    write_atomic(path, buffer.getbuffer())


def atomic_checkpoint_io() -> Any:
    """Lightning's ``TorchCheckpointIO`` with atomic saves (:func:`save_atomic`): a
    failed save (no space, an interrupt) never replaces a good ``last.ckpt`` with a
    partial one. (Lightning is imported here, not with this module.)"""
    from lightning.fabric.plugins.io.torch_io import TorchCheckpointIO

    class AtomicCheckpointIO(TorchCheckpointIO):
        def save_checkpoint(
            self, checkpoint: dict[str, Any], path: Any, storage_options: Any = None
        ) -> None:
            if storage_options is not None:
                raise TypeError(f"{type(self).__name__} takes no storage_options")
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            save_atomic(checkpoint, path)

    return AtomicCheckpointIO()


def machine_memory() -> int:
    """Bytes of memory this process may use: the physical memory, or a smaller
    cgroup limit."""
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    for limit_file in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = Path(limit_file).read_text().strip()
        except OSError:
            continue
        if text.isdigit():
            total = min(total, int(text))
    return total


def idle_cores(samples: int = 3, interval: float = 0.01) -> int:
    """The cores of this process not busy with other processes: ``max(1, cores − busy)``,
    ``busy`` the larger of the 1-minute load average (rounded) and the other processes
    runnable now (the median of ``samples`` reads of ``/proc/loadavg`` ``interval`` s
    apart, :func:`runnable_others`). The load average alone lags: two fits started at
    the same moment each saw both cores idle, took 2 threads, and ran 4.6× slower than
    with 1 each. On 2 shared cores a second busy process makes 2 OpenMP threads wait for
    each other at every operation; 1 thread then runs as fast as on an idle machine
    (BENCHMARKS.md, threads under load)."""
    import statistics
    import time

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    try:
        busy = round(os.getloadavg()[0])
    except OSError:
        busy = 0
    now = []
    for i in range(samples):
        if i:
            time.sleep(interval)
        now.append(runnable_others())
    busy = max(busy, round(statistics.median(now)))
    return max(1, min(cores or 1, (cores or 1) - busy))


def runnable_others(loadavg: str | None = None) -> int:
    """The processes runnable now besides this one: the fourth field of
    ``/proc/loadavg`` (``"0.99 1.68 1.81 3/345 12345"``: 3 runnable, this one counted)
    minus one; 0 where the file is missing (not Linux)."""
    if loadavg is None:
        try:
            loadavg = Path("/proc/loadavg").read_text()
        except OSError:
            return 0
    try:
        return max(0, int(loadavg.split()[3].split("/")[0]) - 1)
    except (IndexError, ValueError):
        return 0


def require_memory(nbytes: float, what: str) -> None:
    """``ValueError`` if ``nbytes`` (an estimate) exceeds :func:`machine_memory`."""
    have = machine_memory()
    if nbytes > have:
        raise ValueError(
            f"{what} needs about {_size(nbytes)} of memory; this machine has {_size(have)}"
        )


def _size(n: float) -> str:
    units = ("B", "KB", "MB", "GB", "TB", "PB")
    k = 0
    while n >= 1000 and k < len(units) - 1:
        n, k = n / 1000, k + 1
    return f"{n:.3g} {units[k]}"
