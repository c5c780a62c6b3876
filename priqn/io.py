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
from collections.abc import Iterator
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
"""Sidecar of a torch file: the SHA-256 of its bytes (torch.load does not verify them)."""


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


def torch_load(path: str | os.PathLike, what: str, remedy: str, map_location: Any = "cpu") -> Any:
    """``torch.load`` whose failure on a damaged file (truncated, bit-flipped, empty) is a
    one-line :class:`PriqnError` naming the file, what it is and what to do."""
    import pickle
    import zipfile

    import torch

    sidecar = Path(str(path) + CHECKSUM_SUFFIX)
    if sidecar.is_file():
        try:
            want = sidecar.read_text(encoding="utf-8").strip()
            have = sha256_file(path)
        except OSError as exc:
            raise PriqnError(
                f"{path}: cannot read {what} ({exc.strerror or exc}); {remedy}"
            ) from None
        if want != have:
            raise PriqnError(
                f"{path}: damaged or unreadable {what} (its SHA-256 does not match "
                f"{sidecar.name}); {remedy}"
            )
    try:
        return torch.load(path, map_location=map_location, weights_only=False)
    except (RuntimeError, EOFError, OSError, ValueError, KeyError, zipfile.BadZipFile,
            pickle.UnpicklingError) as exc:  # fmt: skip
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise PriqnError(
            f"{path}: damaged or unreadable {what} ({type(exc).__name__}"
            f"{': ' + first[:120] if first else ''}); {remedy}"
        ) from None


def _as_user_error(exc: OSError, target: Path) -> PriqnError:
    if exc.errno == errno.ENOSPC:
        return PriqnError(f"{target}: no space left on device; free some space and retry")
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return PriqnError(f"{target}: cannot write here ({exc.strerror})")
    return PriqnError(f"{target}: cannot write ({exc.strerror or exc})")
