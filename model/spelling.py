"""Did you mean: the known name closest to a misspelt one, worded once for every message that suggests one.

The lowest layer holds it so that every layer's errors (a rig file's key, a registered backend, a command
line's option) suggest the same way and with the same words.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable

#: How alike a known name must be to be suggested (difflib's ratio, 0..1): its default, which keeps
#: a suggestion to names that share most of their letters in order.
CUTOFF = 0.6


def closest(word: str, known: Iterable[str]) -> str | None:
    """The one of ``known`` closest to ``word`` if it is alike enough (``CUTOFF``), else None."""
    close = difflib.get_close_matches(word, list(known), n=1, cutoff=CUTOFF)
    return close[0] if close else None


def did_you_mean(word: object, known: Iterable[str], *, aside: bool = False) -> str:
    """``"; did you mean 'x'?"`` for the closest of ``known`` to a misspelt ``word``, else ``""``.

    ``aside`` words it as a parenthesis, ``" (did you mean 'x'?)"``, for a message that goes on after it.
    A ``word`` that is not a string (a number where a name was expected) has no suggestion.
    """
    found = closest(word, known) if isinstance(word, str) else None
    if found is None:
        return ""
    return f" (did you mean {found!r}?)" if aside else f"; did you mean {found!r}?"
