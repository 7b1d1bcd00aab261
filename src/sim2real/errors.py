"""The one exception type that the CLI turns into a single line on stderr and exit code 2, and
:func:`reason`, which makes a library's error fit on that line."""


class UserError(Exception):
    """Bad input from the user (file, flag, scene, config). Its message is shown as is."""


def reason(e: BaseException) -> str:
    """Why ``e`` happened, in a few words for a message that already names the file: the
    ``strerror`` of an OS or FFmpeg error (without its number and the file name repeated: PyAV
    gives "[Errno 1094995529] Invalid data found when processing input: 'x.mp4'"), else the first
    line of the message, else the exception's type."""
    text = getattr(e, "strerror", None) or str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__
