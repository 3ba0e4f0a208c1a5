"""Atomic file writes: a result file is complete or absent, never half-written."""
from __future__ import annotations

import contextlib
import errno
import json
import os
import tempfile
from pathlib import Path
from typing import Optional

from r2pac_jax.errors import R2pacError


class WriteError(R2pacError, OSError):
    """The project could not write one of its files (disk full, no permission, a file where a
    directory should be, a file-size limit); the message names the path and the fix."""

    def __str__(self) -> str:
        return self.strerror or super().__str__()


_WRITE_HINTS = {
    errno.ENOSPC: "no space left on the disk",
    errno.EDQUOT: "the disk quota is exhausted",
    errno.EFBIG: "the file grew past the file-size limit (ulimit -f)",
    errno.EACCES: "permission denied",
    errno.EPERM: "permission denied",
    errno.EROFS: "the file system is read-only",
    errno.ENOTDIR: "a path component is a file, not a directory",
    errno.EEXIST: "a file stands where a directory should be",
}
_MESSAGE_HINTS = (("No space left", errno.ENOSPC), ("RESOURCE_EXHAUSTED", errno.ENOSPC),
                  ("Disk quota", errno.EDQUOT), ("File too large", errno.EFBIG),
                  ("Permission denied", errno.EACCES), ("Read-only file system", errno.EROFS),
                  ("Not a directory", errno.ENOTDIR))


def write_failure(exc: BaseException) -> Optional[int]:
    """The errno of a write failure inside `exc` (its cause chain, or a library's message that
    wraps one, as orbax's and tensorstore's do), or None if it is not one."""
    seen = 0
    e: Optional[BaseException] = exc
    while e is not None and seen < 10:
        if isinstance(e, OSError) and e.errno in _WRITE_HINTS:
            return e.errno
        text = str(e)
        for needle, code in _MESSAGE_HINTS:
            if needle in text:
                return code
        e = e.__cause__ or e.__context__
        seen += 1
    return None


def as_write_error(exc: BaseException, path, what: str, kept: str = "") -> WriteError:
    """A WriteError naming `what` at `path`, the cause, and what is kept (or `exc` itself re-
    raised by the caller when it is no write failure)."""
    code = write_failure(exc)
    hint = _WRITE_HINTS.get(code, "the write failed")
    fix = {errno.ENOSPC: "free disk space (or choose another --out) and rerun",
           errno.EDQUOT: "free space in your quota and rerun",
           errno.EFBIG: "raise the file-size limit (ulimit -f) and rerun",
           errno.ENOTDIR: "choose a directory path",
           errno.EEXIST: "choose a directory path, not a file",
           }.get(code, "choose a writable location and rerun")
    msg = f"cannot write {what} {path}: {hint}; {fix}"
    if kept:
        msg += f" ({kept})"
    return WriteError(code or errno.EIO, msg)


@contextlib.contextmanager
def writing(path, what: str, kept: str = ""):
    """Turn a write failure inside the block into a WriteError naming `what` and `path`."""
    try:
        yield
    except WriteError:
        raise
    except Exception as e:  # noqa: BLE001 - re-raised unchanged unless it is a write failure
        if write_failure(e) is None:
            raise
        raise as_write_error(e, path, what, kept) from e


def _umask_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


@contextlib.contextmanager
def atomic_path(path, suffix: str = ".tmp"):
    """Yield a temporary path beside `path`; when the block ends without error the file there
    replaces `path` at once (umask's usual mode), otherwise it is removed. Every result file
    (JSON, text, PNG) is written through this one mechanism."""
    path = Path(path)
    with writing(path, "the file", "the previous version, if any, is untouched"):
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
        os.close(fd)
        try:
            yield Path(tmp)
            # mkstemp creates 0600 files; results are shared, so give them the umask's usual mode
            os.chmod(tmp, _umask_mode())
            os.replace(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)


def atomic_write_text(path, text: str) -> Path:
    with atomic_path(path) as tmp:
        with open(tmp, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
    return Path(path)


def atomic_write_json(path, obj) -> Path:
    return atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True, default=_default) + "\n")


def _default(o):
    import numpy as np

    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if hasattr(o, "tolist"):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o)}")


class DirectoryBusy(R2pacError, RuntimeError):
    """Another live process is writing the same run directory."""


def _hold(lock: Path, busy: str):
    """Open `lock` and take its flock (released when the file is closed or the process ends,
    even by SIGKILL), recording the holder in it; DirectoryBusy(`busy` with the holder named
    where <holder> stands) when another live process holds it. The caller made the parent."""
    import fcntl
    import socket

    f = open(lock, "a+")
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        f.seek(0)
        holder = f.read().strip() or "an unknown process"
        f.close()
        raise DirectoryBusy(busy.replace("<holder>", holder)) from None  # paths may hold braces
    f.seek(0)
    f.truncate()
    f.write(f"pid {os.getpid()} on {socket.gethostname()}\n")
    f.flush()
    return f


def lock_file(path, what: str = "file"):
    """Hold `{path}.lock` exclusively (flock; released when the returned file is closed or the
    process ends, even by SIGKILL); DirectoryBusy when another live process holds it."""
    lock = Path(f"{path}.lock")
    with writing(lock, "the lock file"):
        lock.parent.mkdir(parents=True, exist_ok=True)
        lock.touch()
    return _hold(lock, f"the {what} {path} is being written by <holder>; wait for it to "
                       "finish or stop it, then rerun")


def remove_orphaned_temporaries(path) -> list[Path]:
    """Delete the temporaries `atomic_path` leaves beside `path` when its writer was killed.
    Call it only while holding the lock of `path` (no live writer then). Returns what went."""
    path = Path(path)
    gone = []
    for p in path.parent.glob(f".{path.name}.*"):
        if p.is_file():
            p.unlink(missing_ok=True)
            gone.append(p)
    return gone


def lock_directory(path):
    """Hold DIR/.lock exclusively until the returned file is closed or this process ends.

    The lock is the kernel's (flock), so a killed process, even by SIGKILL, releases it: a
    restarted run is never refused by a stale lock, while a second live writer of the same
    directory (a launcher started twice) is refused before it writes anything."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise WriteError(errno.EEXIST, f"{path} is a file, not a directory: choose a directory "
                         "path (for --out, a new or existing run directory)")
    with writing(path, "the directory"):
        path.mkdir(parents=True, exist_ok=True)
        (path / ".lock").touch()
    return _hold(path / ".lock", f"{path} is being written by <holder>; wait for it to "
                                 "finish or stop it, then rerun (with --resume to continue "
                                 "from its last checkpoint)")


# ---------------------------------------------------------------------------------------------
# Directories the project writes into: new, empty, or its own


MARKER = ".r2pac_jax.json"  # written into every directory the project claims
# What a reader is told to change, by the kind of directory
_CHOOSE = {"run": "--out", "table": "--out", "sweep": "--out", "data cache": "R2PAC_DATA_DIR"}


class ForeignDirectory(WriteError):
    """A directory the project would write into holds files it did not write."""


def marker_kind(path) -> Optional[str]:
    """The kind recorded in DIR's marker ('run', 'table', ...), '?' for an unreadable marker,
    None when DIR holds none."""
    m = Path(path) / MARKER
    if not m.is_file():
        return None
    try:
        return str(json.loads(m.read_text()).get("kind", "?"))
    except (ValueError, OSError, AttributeError):
        return "?"


def claim_directory(path, kind: str, legacy=None, check_only: bool = False) -> Path:
    """Make sure the project may write into `path` as a directory of `kind`, and mark it.

    Allowed: a path that does not exist yet, an empty directory, one whose marker says `kind`,
    or one that `legacy(path)` recognises as written by an earlier release (before the marker);
    the marker is then written (unless `check_only`). Anything else, above all a user's own
    folder, raises ForeignDirectory before anything is written there."""
    path = Path(path)
    flag = _CHOOSE.get(kind, "another directory")
    if path.exists() and not path.is_dir():
        raise WriteError(errno.EEXIST, f"{path} is a file, not a directory: choose a directory "
                         f"path (for {flag}, a new directory or one r2pac_jax wrote)")
    if path.is_dir():
        have = marker_kind(path)
        entries = sorted(p.name for p in path.iterdir())
        if have is not None and have not in (kind, "?"):
            raise ForeignDirectory(errno.EEXIST, f"{path} is a {have} directory of r2pac_jax, "
                                   f"not a {kind} directory; nothing was written there: choose "
                                   f"another {flag}")
        ours = (have is not None or not [e for e in entries if e != ".lock"]
                or (legacy is not None and legacy(path)))
        if not ours:
            shown = ", ".join(entries[:4]) + (", ..." if len(entries) > 4 else "")
            raise ForeignDirectory(
                errno.EEXIST, f"{path} is not empty and was not written by r2pac_jax (it holds "
                f"{shown}); nothing was written there: choose a new or empty directory for "
                f"{flag}, or one that an earlier {kind} of r2pac_jax wrote")
        if have == kind or check_only:
            return path
    elif check_only:
        return path
    import time

    atomic_write_json(path / MARKER, dict(kind=kind, written_by="r2pac_jax",
                                          since=time.strftime("%Y-%m-%dT%H:%M:%S")))
    return path


@contextlib.contextmanager
def sigint_deferred():
    """Hold Ctrl-C (SIGINT) until the block ends, then raise KeyboardInterrupt there.

    Used around a run's bookkeeping (log rows, the checkpoint save): an interrupt that lands
    inside orbax's save leaves its writer threads half-done, and they print tracebacks at exit.
    The long part, the compiled training block, stays interruptible at once. Only the main
    thread can hold signals; elsewhere this is a no-op."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    previous = signal.getsignal(signal.SIGINT)
    if previous in (signal.SIG_IGN, None):  # not ours to change (a background job)
        yield
        return
    signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt
