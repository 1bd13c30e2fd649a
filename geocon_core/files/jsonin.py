"""JSON that people write (sidecars, pose logs), read strictly: a key given twice is an error, not
"the last one wins", and a number too long to be one is named with its file.

>>> strict_json('{"a": 1}', "x.json")
{'a': 1}
>>> strict_json('{"a": 1, "a": 2}', "x.json")
Traceback (most recent call last):
...
ValueError: x.json: key 'a' is given twice (a JSON object names each key once)
"""

from __future__ import annotations

import json
from typing import Any

__all__ = ["MAX_NUMBER_CHARS", "strict_json"]

MAX_NUMBER_CHARS = 64
"""A number written with more characters than this is refused (no pose, fps or size needs them)."""


def _object(pairs: list[tuple[str, Any]], where: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"{where}: key {key!r} is given twice (a JSON object names each key once)")
        out[key] = value
    return out


def _number(text: str, where: str, kind: type) -> Any:
    if len(text) > MAX_NUMBER_CHARS:
        raise ValueError(f"{where}: a number of {len(text)} characters ({text[:12]}...) is not a usable value")
    return kind(text)


def _constant(name: str, where: str) -> Any:
    raise ValueError(f"{where}: {name} is not a JSON number (JSON has no NaN or Infinity); write a number or null")


def strict_json(text: str, where: str, *, constants: bool = True) -> Any:
    """Parse ``text`` (the contents of ``where``); ``ValueError`` naming ``where`` for a repeated
    key, an absurdly long number, arrays and objects nested deeper than the parser can follow and,
    without ``constants``, ``NaN`` or ``Infinity`` (which Python's parser accepts and JSON has not);
    ``json.JSONDecodeError`` for text that is not JSON."""
    try:
        return json.loads(
            text,
            object_pairs_hook=lambda pairs: _object(pairs, where),
            parse_int=lambda s: _number(s, where, int),
            parse_float=lambda s: _number(s, where, float),
            parse_constant=None if constants else lambda name: _constant(name, where),
        )
    except RecursionError:
        raise ValueError(
            f"{where}: arrays or objects are nested too deeply to be read (thousands of levels; no GeoCon file "
            "nests more than a few)"
        ) from None
