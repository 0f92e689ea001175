"""Key paths and key names of the configuration schema, for :mod:`controller.config`'s error
messages (file, key, rule)."""

from __future__ import annotations

from pydantic import BaseModel

# The discriminator tags pydantic puts into error locations: right after the entry of a
# discriminated union — a light source (after its list index), a heliostat's ``link``, the
# ``lamps`` section, a bus of ``field.buses`` (after its name). Elsewhere the same words are
# the user's keys ("lamp" is also a channel name of lamps.channels, "command" a key of the
# command driver).
_TAGS = ("sun", "lamp", "serial", "modbus-tcp", "modbus-rtu", "command")


def key_path(loc: tuple) -> str:
    """A pydantic error location as the key path the user wrote (``targets[0].camera``)."""
    out = ""
    for k, part in enumerate(loc):
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in _TAGS and k > 0 and (isinstance(loc[k - 1], int) or loc[k - 1] in ("link", "lamps")
                                          or k > 1 and loc[k - 2] == "buses"):
            continue  # a discriminator tag pydantic inserts; not part of the user's key path
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


def field_names(model: type[BaseModel], seen: set[type] | None = None) -> set[str]:
    """Every key name the configuration schema knows (all nested models)."""
    seen = seen if seen is not None else set()
    if model in seen:
        return set()
    seen.add(model)
    names = set(model.model_fields)
    for f in model.model_fields.values():
        for arg in (f.annotation, *getattr(f.annotation, "__args__", ())):
            for inner in (arg, *getattr(arg, "__args__", ())):
                if isinstance(inner, type) and issubclass(inner, BaseModel):
                    names |= field_names(inner, seen)
    return names


def did_you_mean(key: str, schema: type[BaseModel]) -> str:
    """The hint ` (did you mean 'x'?)` for the key name of ``schema`` closest to ``key``, else ''."""
    import difflib

    close = difflib.get_close_matches(key, sorted(field_names(schema)), n=1, cutoff=0.75)
    return f" (did you mean {close[0]!r}?)" if close else ""
