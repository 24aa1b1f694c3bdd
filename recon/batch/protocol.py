"""What a supervisor and its child process say to each other.

The supervisor starts the child (``python -c``, see :mod:`recon.batch.supervise`) and writes one
frame to its stdin: the item spec, a dict built by :func:`recon.batch.run.run_batch` whose
``job``, ``job_path`` and ``job_prepare`` entries hold a :class:`JobRef`. The child answers on
its original stdout, one frame per message:

- ``("start", pid)`` once the job is imported and prepared (the item's clock starts);
- ``("progress", phase, info)`` for every pipeline progress report;
- ``("done", metrics, elapsed_s)``, ``("error", message, detail, is_timeout, elapsed_s)`` or
  ``("interrupted", elapsed_s)`` at the end.

A frame is a pickle preceded by its length (4 bytes, big-endian). Closing the child's stdin asks
it to stop.
"""

from __future__ import annotations

import importlib
import pickle
import struct
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = ["JobRef", "read_frame", "write_frame"]

_HEADER = struct.Struct("!I")


def write_frame(fh: Any, obj: Any) -> None:
    """Send ``obj`` as one frame and flush.

    Parameters
    ----------
    fh : binary file
    obj : picklable
    """
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    fh.write(_HEADER.pack(len(data)) + data)
    fh.flush()


def _read_exact(fh: Any, n: int) -> bytes | None:
    buf = b""
    while len(buf) < n:
        chunk = fh.read(n - len(buf))
        if not chunk:
            return None
        buf += chunk
    return buf


def read_frame(fh: Any) -> Any:
    """The next frame's object, or None at the end of the stream.

    Parameters
    ----------
    fh : binary file
    """
    head = _read_exact(fh, _HEADER.size)
    if head is None:
        return None
    data = _read_exact(fh, _HEADER.unpack(head)[0])
    return None if data is None else pickle.loads(data)


def _resolve(text: str, path: str | None) -> Callable[..., Any]:
    """The object named ``"module:qualname"``, importing the module (from ``path`` first)."""
    if path and path not in sys.path:
        sys.path.insert(0, path)
    module, _, qualname = text.partition(":")
    obj: Any = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


@dataclass(frozen=True)
class JobRef:
    """The job a child process runs, named so that a fresh interpreter can import it.

    Attributes
    ----------
    target : str
        ``"module:qualname"`` of ``job(spec, on_progress) -> metrics``.
    path : str or None
        Folder put first on ``sys.path`` before importing (for modules outside the installed
        packages, e.g. tests).
    prepare : str or None
        ``"module:qualname"`` of a function the child calls once before the item's clock starts
        (imports, compilation).
    """

    target: str
    path: str | None = None
    prepare: str | None = None

    @classmethod
    def of(cls, job: Callable[..., Any] | str | JobRef) -> JobRef:
        """A reference to ``job``: a module-level function, a ``"module:function"`` or a JobRef.

        Raises
        ------
        ValueError
            ``job`` is a lambda, a local function or has no module.
        """
        if isinstance(job, JobRef):
            return job
        if isinstance(job, str):
            return cls(job)
        qualname = getattr(job, "__qualname__", "")
        module = getattr(job, "__module__", None)
        if not module or not qualname or "<" in qualname:
            raise ValueError(f"job must be a module-level function, got {job!r}")
        path = None
        mod = sys.modules.get(module)
        if mod is not None and getattr(mod, "__file__", None):
            path = str(Path(mod.__file__).resolve().parent)
            if module.count("."):
                path = str(Path(path).parents[module.count(".") - 1])
        return cls(f"{module}:{qualname}", path)

    def to_spec(self) -> dict[str, str | None]:
        """The item-spec entries ``job``, ``job_path`` and ``job_prepare``."""
        return {"job": self.target, "job_path": self.path, "job_prepare": self.prepare}

    @classmethod
    def from_spec(cls, spec: Any) -> JobRef:
        """The reference held by an item spec (see :meth:`to_spec`)."""
        return cls(spec["job"], spec.get("job_path"), spec.get("job_prepare"))

    def load(self) -> tuple[Callable[..., Any], Callable[[], Any] | None]:
        """Import the job and its ``prepare`` function (None when it has none)."""
        job = _resolve(self.target, self.path)
        prepare = _resolve(self.prepare, self.path) if self.prepare else None
        return job, prepare
