"""The one exception type users see: a plain message, never a traceback."""


class MocapError(Exception):
    """A problem with the user's input or settings, worded for the user.

    The message names the file (or setting) at fault and says what to do.
    The command-line entry point prints it and exits with status 2.
    """
