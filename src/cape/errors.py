"""Errors the ``cape`` command reports as one clear message instead of a traceback."""


class CapeError(Exception):
    """A problem the user can fix: the message names the file, the field and the fix."""
