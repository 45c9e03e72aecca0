"""What reaches the user's console: progress bars only on a terminal (:func:`bar`, the one
helper every long loop draws its bar with) and no third-party log lines (:func:`quiet_third_party`).

A bar redrawn into a redirected log (a sweep's ``> log.txt``, a cluster job's output, CI) is
hundreds of lines of carriage returns; :func:`bar` draws tqdm's bar on stderr only when stderr
is a terminal, and a no-op bar (same methods) otherwise.
"""

from __future__ import annotations

import sys
from typing import Any

__all__ = ["bar", "on_terminal", "quiet_third_party", "THIRD_PARTY_LOGGERS"]

#: libraries whose log lines are theirs, not the user's (matplotlib's "building the font cache"
#: on a first run, PIL's plugin chatter): only their errors reach the console
THIRD_PARTY_LOGGERS = ("matplotlib", "PIL", "fontTools", "numexpr", "urllib3")


def on_terminal() -> bool:
    """Whether stderr is a terminal (where a progress bar belongs)."""
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError):  # closed or replaced stream
        return False


def bar(enabled: bool | None = None, **kwargs: Any) -> Any:
    """A tqdm bar (``kwargs`` as :class:`tqdm.tqdm`), disabled when ``enabled`` is ``False``
    or stderr is not a terminal; ``enabled=None`` leaves the choice to ``kwargs`` (e.g.
    ``delay=3``: only for a loop longer than 3 s)."""
    from tqdm.auto import tqdm

    return tqdm(disable=enabled is False or not on_terminal(), **kwargs)


def quiet_third_party() -> None:
    """Raise the level of :data:`THIRD_PARTY_LOGGERS` to ERROR (the app and ``sssbench-report``
    call it at start: their console carries sssbench's own lines only)."""
    import logging

    for name in THIRD_PARTY_LOGGERS:
        logging.getLogger(name).setLevel(logging.ERROR)
