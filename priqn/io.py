"""Atomic file writes: nothing already written is lost or half-written.

Every artefact (configs, metrics, checkpoints, tables, manifests) is written to a
temporary file in the destination folder, flushed, fsync'ed and then renamed over
the target. A crash (even ``kill -9``) leaves either the old or the new file.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import IO, Any

from priqn.errors import PriqnError

_UMASK = os.umask(0)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "wb") -> Iterator[IO[Any]]:
    """Open a temp file beside ``path``; on success fsync and rename it over ``path``."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open supports 'w' and 'wb', not {mode!r}")
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    except OSError as exc:
        raise _as_user_error(exc, target) from exc
    tmp = Path(tmp_name)
    try:
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; give the file the usual mode
        with os.fdopen(fd, mode, **({"encoding": "utf-8"} if mode == "w" else {})) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise _as_user_error(exc, target) from exc
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def remove_stale_temp_files(folder: str | os.PathLike) -> int:
    """Delete temp files a killed :func:`atomic_open` left under ``folder`` (recursively).

    Only names of :func:`atomic_open`'s form (``.<target>.<random>.tmp``) are removed.
    Call it only where no other writer can be active (a run folder being opened by its
    one trainer). Returns how many were removed.
    """
    removed = 0
    for tmp in Path(folder).rglob(".*.tmp"):
        if tmp.is_file():
            tmp.unlink(missing_ok=True)
            removed += 1
    return removed


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_open(path, "wb") as fh:
        fh.write(data)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    with atomic_open(path, "w") as fh:
        fh.write(text)


def atomic_write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write ``obj`` as indented, key-sorted JSON (stable bytes for stable input)."""
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=str) + "\n")


def read_json(path: str | os.PathLike) -> Any:
    """Read a JSON file; a missing or unreadable file is a one-line :class:`PriqnError`."""
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise PriqnError(f"{path}: cannot read JSON ({exc})") from exc


def sha256_file(path: str | os.PathLike) -> str:
    """Hex SHA-256 of a file's bytes."""
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


CHECKSUM_SUFFIX = ".sha256"
"""Sidecar of a torch file: the SHA-256 of its bytes (torch.load does not verify them).
It detects damage, not tampering: whoever can replace a file can rewrite its sidecar, which
is why :func:`torch_load` never unpickles anything but tensors and plain data."""


def atomic_torch_save(obj: Any, path: str | os.PathLike) -> None:
    """``torch.save`` through a temp file and rename (checkpoints survive kill -9), with a
    ``<file>.sha256`` sidecar so :func:`torch_load` detects flipped bits."""
    import hashlib
    import io as _io

    import torch

    buf = _io.BytesIO()
    torch.save(obj, buf)
    data = buf.getvalue()
    atomic_write_text(str(path) + CHECKSUM_SUFFIX, hashlib.sha256(data).hexdigest() + "\n")
    atomic_write_bytes(path, data)


def torch_load(
    path: str | os.PathLike,
    what: str,
    remedy: str,
    map_location: Any = "cpu",
    allow: Sequence[Any] = (),
) -> Any:
    """``torch.load(..., weights_only=True)``: tensors and plain data (dicts, lists,
    numbers, strings) only, never an arbitrary pickled object, so a file from anyone runs
    no code. ``allow``: the few extra types admitted (``torch.serialization.safe_globals``
    entries; :mod:`priqn.run.checkpoint` admits numpy arrays for old checkpoints). A damaged,
    truncated or foreign file -- one naming any other Python object -- is a one-line
    :class:`PriqnError` naming the file, what it is and what to do."""
    import pickle
    import zipfile

    import torch

    _check_sidecar(Path(path), what, remedy)
    try:
        with torch.serialization.safe_globals(list(allow)):
            return torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as exc:
        raise PriqnError(f"{path}: {_refusal(str(exc), what)}; {remedy}") from None
    except (RuntimeError, EOFError, OSError, ValueError, KeyError, TypeError,
            AttributeError, zipfile.BadZipFile) as exc:  # fmt: skip
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise PriqnError(
            f"{path}: damaged or unreadable {what} ({type(exc).__name__}"
            f"{': ' + first[:120] if first else ''}); {remedy}"
        ) from None


def _check_sidecar(path: Path, what: str, remedy: str) -> None:
    """A ``<file>.sha256`` sidecar, when present, must match the file's bytes."""
    sidecar = Path(str(path) + CHECKSUM_SUFFIX)
    if not sidecar.is_file():
        return
    try:
        want = sidecar.read_text(encoding="utf-8").strip()
        have = sha256_file(path)
    except OSError as exc:
        raise PriqnError(f"{path}: cannot read {what} ({exc.strerror or exc}); {remedy}") from None
    if want != have:
        raise PriqnError(
            f"{path}: damaged or unreadable {what} (its SHA-256 does not match "
            f"{sidecar.name}); {remedy}"
        )


def _refusal(message: str, what: str) -> str:
    """One line for torch's weights-only refusal: which Python object the file names (a
    pickle that would run code, or a type priqn never stores), else damage."""
    import re

    inner = message.split("WeightsUnpickler error:")[-1]  # torch's own words, if any
    named = re.search(r"GLOBAL (\S+) (?:was not an allowed global|whose module)", inner)
    if named is None:
        named = re.search(r"(?:unrecognized function|but got) (<[^>]*>|\S+)", inner)
    if named is not None:
        return (
            f"refused: not a priqn {what}: it names the Python object {named.group(1)}, and "
            "priqn loads only tensors and plain data from torch files (unpickling other "
            "objects could run code)"
        )
    lines = inner.strip().splitlines()
    first = lines[0][:120] if lines else ""
    return f"damaged or unreadable {what} (UnpicklingError{': ' + first if first else ''})"


def ensure_dir(path: str | os.PathLike) -> Path:
    """``path`` as a folder, made with its parents if need be; a folder that cannot be made
    (not writable, a file in the way, ``/proc``) is a one-line :class:`PriqnError` naming it."""
    folder = Path(path)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _as_user_error(exc, folder) from None
    return folder


def missing_folders(path: str | os.PathLike) -> list[Path]:
    """``path`` and its parents that do not exist yet, innermost first: the folders that
    making ``path`` would create (:func:`remove_empty_folders` takes them away again)."""
    folder = Path(path).absolute()
    return [p for p in (folder, *folder.parents) if not p.exists() and not p.is_symlink()]


def remove_empty_folders(folders: Sequence[Path]) -> None:
    """Remove each of ``folders`` (innermost first, as :func:`missing_folders` lists them)
    that holds no file, with its empty sub-folders; one holding a file stays, and so does
    anything that cannot be removed. Only for folders this process made."""
    for folder in folders:
        if not folder.is_dir() or folder.is_symlink():
            continue
        for sub, _, _ in sorted(os.walk(folder), key=lambda w: -len(Path(w[0]).parts)):
            with contextlib.suppress(OSError):
                os.rmdir(sub)  # fails, and so stays, unless empty


@contextlib.contextmanager
def removed_on_failure(path: str | os.PathLike) -> Iterator[None]:
    """The folders the block makes for ``path`` (it, its parents) are removed again when
    it raises and leaves them empty: a refused command leaves no empty output folder."""
    made = missing_folders(path)
    try:
        yield
    except BaseException:
        remove_empty_folders(made)
        raise


def check_writable(path: str | os.PathLike, where: str) -> Path:
    """``path`` as a file that :func:`atomic_open` can write later: its folder made (or
    there) and a temporary file made in it now, then all of it removed again, so a long
    command refuses an output it could not write before it starts, and leaves nothing.
    A one-line :class:`PriqnError` names ``where`` (the flag) and the path."""
    target = Path(path)
    if target.is_dir():
        raise PriqnError(f"{where} {target}: a folder; expected a file to write")
    made = missing_folders(target.parent)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise PriqnError(f"{where} {_as_user_error(exc, target)}") from None
    finally:
        remove_empty_folders(made)
    return target


def _as_user_error(exc: OSError, target: Path) -> PriqnError:
    if exc.errno == errno.ENOSPC:
        return PriqnError(f"{target}: no space left on device; free some space and retry")
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return PriqnError(f"{target}: cannot write here ({exc.strerror})")
    return PriqnError(f"{target}: cannot write ({exc.strerror or exc})")
