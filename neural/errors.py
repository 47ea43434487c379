"""Errors a user can act on. The CLI prints their message alone (no traceback) and exits non-zero."""

import contextlib
import errno


class ShellsimError(Exception):
    """A failure the user can act on; the message names the file or option and the problem."""


class InputError(ShellsimError, ValueError):
    """Bad user input: a malformed or missing file, an unknown option value, an inconsistent asset."""


#: The failures of a write a user can act on (disk full, failing disk, no permission), as they are told.
WRITE_CAUSES = {
    errno.ENOSPC: "no space left on device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file too large for the file system",
    errno.EIO: "input/output error (the disk failed)",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
}

_ADVICE = {
    errno.ENOSPC: "free space and run the same command to continue",
    errno.EDQUOT: "free space and run the same command to continue",
    errno.EFBIG: "write to another file system",
    errno.EIO: "check the disk and run the same command to continue",
}


class WriteError(ShellsimError):
    """Writing the file ``path`` failed with the OS error number ``errno`` (one of :data:`WRITE_CAUSES`):
    one line naming the file, the cause, what was being written (``doing``) and what was kept (``kept``)."""

    def __init__(self, path, errno: int, doing: str = "", kept: str = ""):
        self.path, self.errno, self.doing, self.kept = str(path), errno, doing, kept
        advice = _ADVICE.get(errno, "make it writable and run the same command to continue")
        parts = [f"{self.path}: {WRITE_CAUSES[errno]}" + (f" ({doing})" if doing else ""), kept, advice]
        super().__init__("; ".join(part for part in parts if part))


@contextlib.contextmanager
def write_failures(path, doing: str = "", kept: str = ""):
    """Turn an ``OSError`` of :data:`WRITE_CAUSES` (or a :class:`WriteError`) raised inside into a
    :class:`WriteError` naming ``path``, ``doing`` and ``kept``; other errors pass unchanged."""
    try:
        yield
    except (WriteError, OSError) as err:
        if err.errno not in WRITE_CAUSES:
            raise
        raise WriteError(path, err.errno, doing, kept) from err
