"""The one exception type that the CLI turns into a single line on stderr and exit code 2."""


class UserError(Exception):
    """Bad input from the user (file, flag, scene, config). Its message is shown as is."""
