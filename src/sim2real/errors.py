"""The one exception type that the CLI turns into a single line on stderr and exit code 2, and
:func:`reason`, which makes a library's error fit on that line, and :func:`machine_error`, the line
for a full disk or a forbidden place."""

import errno
import os


class UserError(Exception):
    """Bad input from the user (file, flag, scene, config). Its message is shown as is."""


def reason(e: BaseException) -> str:
    """Why ``e`` happened, in a few words for a message that already names the file: the
    ``strerror`` of an OS or FFmpeg error (without its number and the file name repeated: PyAV
    gives "[Errno 1094995529] Invalid data found when processing input: 'x.mp4'"), else the first
    line of the message, else the exception's type."""
    text = getattr(e, "strerror", None) or str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


_MACHINE = {
    errno.ENOSPC: "free space on that disk or write elsewhere",
    errno.EDQUOT: "free space within your quota or write elsewhere",
    errno.EROFS: "write elsewhere",
    errno.EACCES: "check its permissions",
    errno.EPERM: "check its permissions",
}
"""Failures of the machine a command runs on, not of the command, with what to do about each."""


def machine_error(e: BaseException) -> str | None:
    """The one line for a failure of the machine rather than of sim2real: a full disk, a quota,
    a read-only or forbidden place, found as an ``OSError`` in ``e`` or among the exceptions it
    was raised from (a library may wrap it); None for anything else. Every output is written
    under a temporary name first, so such a failure leaves nothing half-written under its name."""
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError) and e.errno in _MACHINE:
            where = f" ({e.filename})" if e.filename else ""
            return f"{e.strerror or os.strerror(e.errno)}{where}: {_MACHINE[e.errno]}"
        e = e.__cause__ or e.__context__
    return None
