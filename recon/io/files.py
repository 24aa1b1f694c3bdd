"""Output files: path checks before any work, and the one layer of atomic writes.

:func:`check_output_path` refuses, before anything is computed, an output that is an input
(under any spelling, symlink or hard link), a folder, or lies in a missing folder or in one
where no file can be created (a read-only mount, no write permission).

:func:`atomic_outputs` is the only place that writes output files: each file is written to a
temporary beside its destination and all of them are moved into place together when the block
succeeds; on any exception, ``KeyboardInterrupt`` included, every temporary is removed and no
destination is touched. :func:`atomic_output` is the same for a single file, or joins a file to
an enclosing set, so writers never wrap a file twice.

:func:`check_regular_file` (from :mod:`.common`, where the readers' checks are) refuses an
input that is a pipe or a device (``<(cat s.xyz)``, a FIFO): the readers need a file they can
measure and read more than once.

Temporaries are named ``.<name>.<pid>-<8 hex digits>.tmp<suffix>``: hidden, unique per
process, and with the destination's suffix, so writers that choose the format from the
extension work (:mod:`recon.batch` removes those of killed workers by this pattern).
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import secrets
from collections.abc import Iterator, Sequence
from pathlib import Path

from .common import check_regular_file, input_error

__all__ = [
    "AtomicOutputs",
    "atomic_output",
    "atomic_outputs",
    "check_output_path",
    "check_regular_file",
    "folders_undone_on_failure",
]


def check_output_path(
    path: str | os.PathLike[str],
    inputs: Sequence[str | os.PathLike[str]] = (),
    mkdir: bool = False,
    *,
    mkdir_option: str | None = "--mkdir",
    taken: Sequence[tuple[str | os.PathLike[str], str]] = (),
) -> Path:
    """Validate an output path before any work is done.

    Parameters
    ----------
    path : path-like
        The file to be written.
    inputs : sequence of path-like
        Input files of the run; writing onto one of them is refused.
    mkdir : bool
        Create a missing parent folder instead of failing.
    mkdir_option : str or None
        The caller's option that creates the folder, named in the error; None when it has none.
    taken : sequence of (path-like, str)
        Other outputs of the run and what each is (``"the mesh (-o)"``): writing onto one of
        them is refused, naming it.

    Returns
    -------
    Path

    Raises
    ------
    InputError
        ``path`` is an input, a directory, or its folder is missing (without ``mkdir``) or
        not writable (a read-only file system; permissions, for a user other than root).
    """
    out = Path(path)
    if str(out) in ("", "."):
        raise input_error(out, "empty output path")
    if out.is_dir():
        raise input_error(out, "is a directory; give an output file name")
    resolved = out.resolve()
    for inp in inputs:
        ip = Path(inp)
        same = resolved == ip.resolve()
        if not same and out.exists() and ip.exists():
            with contextlib.suppress(OSError):
                same = os.path.samefile(out, ip)
        if same:
            raise input_error(
                out, "refusing to overwrite an input file; choose another output name"
            )
    for other, what in taken:
        if resolved == Path(other).resolve():
            raise input_error(out, f"is also {what}; give each output its own name")
    parent = resolved.parent
    if not parent.exists():
        if not mkdir:
            hint = f"create it or use {mkdir_option}" if mkdir_option else "create it first"
            raise input_error(out, f"folder '{out.parent}' does not exist ({hint})")
        missing = [parent, *(a for a in parent.parents if not a.exists())]  # deepest first
        try:
            parent.mkdir(parents=True, exist_ok=True)
            made = _MADE.get()
            if made is not None:  # undone if the command fails (folders_undone_on_failure)
                made.extend(reversed(missing))
        except OSError as exc:
            raise input_error(
                out, f"cannot create folder '{out.parent}': {exc.strerror or exc}"
            ) from None
    elif not parent.is_dir():
        raise input_error(out, f"'{out.parent}' is not a folder")
    # the temporary is made beside the path as given, and renamed onto it (onto a symlink
    # itself, not its target): that folder is the one that must take a new file
    _check_writable(out, Path(os.path.abspath(out)).parent)
    return out


def _check_writable(out: Path, parent: Path) -> None:
    """Refuse ``out`` when no file can be created in its folder ``parent``: a read-only mount
    (``os.access`` says so even to root) or, for other users, the folder's permissions. The
    writers create a temporary beside the destination (:class:`AtomicOutputs`), which takes
    write and search permission on the folder, whether or not ``out`` exists. A full disk
    cannot be told in advance: the write reports it."""
    if os.access(parent, os.W_OK | os.X_OK):
        return
    read_only = False
    with contextlib.suppress(OSError, AttributeError):
        read_only = bool(os.statvfs(parent).f_flag & os.ST_RDONLY)
    why = "it is on a read-only file system" if read_only else "permission denied"
    raise input_error(out, f"cannot write in folder '{out.parent}': {why}")


#: The folders ``check_output_path(mkdir=True)`` made inside :func:`folders_undone_on_failure`.
_MADE: contextvars.ContextVar[list[Path] | None] = contextvars.ContextVar(
    "oprecon_folders_made", default=None
)


@contextlib.contextmanager
def folders_undone_on_failure() -> Iterator[None]:
    """Remove again, when the block fails (an error or Ctrl-C), the output folders that
    :func:`check_output_path` made for it with ``mkdir`` and that are still empty: a failed
    ``fit --mkdir`` left its empty folders behind."""
    made: list[Path] = []
    token = _MADE.set(made)
    try:
        yield
    except BaseException:
        for folder in reversed(made):  # the deepest first
            with contextlib.suppress(OSError):
                folder.rmdir()  # only when empty
        raise
    finally:
        _MADE.reset(token)


class AtomicOutputs:
    """Output files written all or nothing (see :func:`atomic_outputs`, which makes one)."""

    def __init__(self) -> None:
        self._pending: list[tuple[Path, Path]] = []  # (temporary, destination)
        self._current: Path | None = None  # the file being written or moved, for messages

    def temporary(self, path: str | os.PathLike[str]) -> Path:
        """Reserve the temporary file to write for destination ``path``.

        Parameters
        ----------
        path : path-like
            Final destination, moved into place when the set is committed.

        Returns
        -------
        Path
            An empty file beside ``path`` with the same suffix.

        Raises
        ------
        InputError
            The temporary cannot be created (names ``path``).
        """
        dest = Path(path)
        tmp = dest.parent / f".{dest.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp{dest.suffix}"
        try:
            open(tmp, "xb").close()  # noqa: SIM115 - reserve the name (respects the umask)
        except OSError as exc:
            raise input_error(dest, f"cannot write: {exc.strerror or exc}") from None
        self._pending.append((tmp, dest))
        self._current = dest
        return tmp

    def commit(self) -> None:
        """Move every temporary into place, the first reserved last.

        The first file of a set is the main output (the mesh of a fit): when it exists, so do
        the others.
        """
        while self._pending:
            tmp, self._current = self._pending[-1]
            os.replace(tmp, self._current)
            self._pending.pop()

    def discard(self) -> None:
        """Remove the temporaries not yet moved into place."""
        for tmp, _ in self._pending:
            with contextlib.suppress(OSError):
                tmp.unlink()
        self._pending.clear()

    def error(self, exc: OSError) -> Exception:
        """``exc`` as an :class:`~recon.errors.InputError` naming the file being written."""
        return input_error(self._current, f"cannot write: {exc.strerror or exc}")


@contextlib.contextmanager
def atomic_outputs() -> Iterator[AtomicOutputs]:
    """A set of output files that appear together when the block succeeds, or not at all.

    Reserve each file with :meth:`AtomicOutputs.temporary` (or :func:`atomic_output` with the
    set, or a writer's ``outputs=`` argument) and write it inside the block. On success every
    file is moved into place; on any exception, including ``KeyboardInterrupt``, every
    temporary is removed and no destination is touched. An ``OSError`` (disk full, permission
    denied) becomes an :class:`~recon.errors.InputError` naming the file being written.

    Yields
    ------
    AtomicOutputs
    """
    outputs = AtomicOutputs()
    try:
        yield outputs
        outputs.commit()
    except BaseException as exc:
        outputs.discard()
        if isinstance(exc, OSError):
            raise outputs.error(exc) from None
        raise


@contextlib.contextmanager
def atomic_output(
    path: str | os.PathLike[str], outputs: AtomicOutputs | None = None
) -> Iterator[Path]:
    """Write one file to a temporary beside ``path`` and move it into place on success.

    The temporary keeps the suffix of ``path``. On any exception, including
    ``KeyboardInterrupt``, it is removed and ``path`` is left untouched; an ``OSError`` (disk
    full, permission denied) becomes an :class:`~recon.errors.InputError` naming ``path``.

    Parameters
    ----------
    path : path-like
        Final destination.
    outputs : AtomicOutputs, optional
        Join this set instead: the file is moved into place (or removed) with the others when
        the set's block ends.

    Yields
    ------
    Path
        The temporary file to write.
    """
    if outputs is not None:
        yield outputs.temporary(path)
        return
    with atomic_outputs() as own:
        yield own.temporary(path)
