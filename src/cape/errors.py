"""Errors the ``cape`` command reports as one clear message instead of a traceback."""


class CapeError(Exception):
    """A problem the user can fix: the message names the file, the field and the fix."""


def one_line(message: str) -> str:
    """``message`` as one line: a character that would break it (a newline, a carriage return,
    a Unicode line or paragraph separator, from a name the user gave) is shown escaped."""
    breaks = "\n\r\v\f\x1c\x1d\x1e\x85\u2028\u2029"
    return "".join(repr(c)[1:-1] if c in breaks else c for c in message)


def limit_text(resource_id: int) -> str:
    """This process's soft limit of ``resource_id`` (``resource.RLIMIT_*``) as a message says
    it: a number, or "unlimited"."""
    import resource

    soft = resource.getrlimit(resource_id)[0]
    return "unlimited" if soft == resource.RLIM_INFINITY else str(soft)
