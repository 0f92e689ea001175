"""Lists of ids an operator gives — ``--heliostats H01,H02`` on the command line, ``{"heliostats":
["H01", "H02"]}`` in a console request — checked by one piece of code, so the CLI and the console
refuse the same things: no id, an id that is not text, an empty id, an id given twice (a night
would record it twice and abort), an id the plant does not have. InputError names the option
or field and the value (exit 2; HTTP 400)."""

from __future__ import annotations

from collections.abc import Callable

from controller.errors import InputError

MAX_IDS = 100_000  # more than any field has
MAX_ID_CHARS = 200


def id_list(ids: object, option: str, known: Callable[[str], object] | None = None) -> list[str]:
    """``ids`` (a list) as given, each checked; ``known(id)`` raises for an id the plant lacks."""
    if not isinstance(ids, list) or not all(isinstance(i, str) for i in ids):
        raise InputError(f"{option} must be a list of ids (text), got {str(ids)[:60]}")
    if not ids:
        raise InputError(f"{option}: give at least one id")
    if len(ids) > MAX_IDS:
        raise InputError(f"{option}: {len(ids)} ids, at most {MAX_IDS}")
    seen: set[str] = set()
    for i in ids:
        if not i.strip() or len(i) > MAX_ID_CHARS or not i.isprintable():
            raise InputError(f"{option}: {i[:40]!r} is not an id (printable text, 1 to {MAX_ID_CHARS} "
                             "characters)")
        if i in seen:
            raise InputError(f"{option}: {i!r} is given twice")
        seen.add(i)
    for i in ids if known is not None else ():
        known(i)
    return ids


def split_ids(text: str, option: str, known: Callable[[str], object] | None = None,
              what: str = "heliostat id") -> list[str]:
    """The ids of a comma-separated option (``H01,H02``; blanks around commas ignored), as
    :func:`id_list` checks them."""
    ids = [i.strip() for i in text.split(",") if i.strip()]
    if not ids:
        raise InputError(f"{option}: no {what} in {text!r} (give ids separated by commas)")
    return id_list(ids, option, known)


def campaign_name(name: object, option: str) -> str:
    """A campaign's name (``--name``; the console's ``name``): printable text of 1 to
    :data:`MAX_ID_CHARS` characters, blanks around it dropped."""
    if not isinstance(name, str) or not name.strip() or len(name) > MAX_ID_CHARS or not name.isprintable():
        raise InputError(f"{option}: {str(name)[:40]!r} is not a campaign name (printable text, 1 to "
                         f"{MAX_ID_CHARS} characters)")
    return name.strip()
