"""Sizes in bytes from text such as ``'8G'`` (``io.max_memory``, ``tiling.memory``)."""

from __future__ import annotations

from .errors import ConfigError

__all__ = ["parse_size"]


_SIZE_UNITS = {"": 1, "B": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


def parse_size(text: str | float, key: str = "size") -> int:
    """Bytes of a size such as ``'8G'``, ``'512M'``, ``'1.5GiB'``, ``4e9`` or ``4000000000``.

    Units are powers of 1024; a plain number (a YAML integer or a string of digits) is bytes.

    Raises
    ------
    ConfigError
        Naming ``key`` when the text is not a positive size.

    Examples
    --------
    >>> parse_size("8G"), parse_size("512MiB"), parse_size("1000"), parse_size(4000000000)
    (8589934592, 536870912, 1000, 4000000000)
    """
    import re

    if isinstance(text, bool):
        raise ConfigError(
            f"{key}: {text!r} is not a size; write e.g. 8G, 512M or a number of bytes"
        )
    if isinstance(text, int):  # exact, however large
        if not 0 < text < 2**63:
            raise ConfigError(f"{key}: {text!r} must be a positive size, e.g. 8G")
        return text
    if isinstance(text, float):
        value, unit = text, ""
    else:
        m = re.fullmatch(
            r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([kKmMgGtT]?)(?:i?[bB])?\s*", str(text)
        )
        if m is None:
            raise ConfigError(
                f"{key}: {text!r} is not a size; write e.g. 8G, 512M or a number of bytes"
            )
        value, unit = float(m.group(1)), m.group(2).upper()
    size = value * _SIZE_UNITS[unit]
    if not (size > 0 and size < 2.0**63):
        raise ConfigError(f"{key}: {text!r} must be a positive size, e.g. 8G")
    return int(size)
