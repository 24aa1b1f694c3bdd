"""Validated frozen dataclasses: one machinery for every user-facing schema.

A *schema* is a frozen dataclass deriving from :class:`Schema` whose fields are declared with
:func:`option` (a default, a line of documentation and the allowed range or choices). Whether it
is built in code (``DynamicsConfig(dt=0.1)``) or from a YAML mapping (:func:`from_dict`), every
field goes through the same checks in ``__post_init__``:

- :func:`coerce` checks the value against the field's annotation and converts it (an int where a
  float is expected becomes a float; floats must be finite; ``None`` only for ``X | None``);
- :func:`check_range` checks it against the ``option`` bounds and choices;
- :meth:`Schema.check` runs the constraints that involve more than one field.

Every error is a :class:`~recon.errors.ConfigError` that names the dotted key
(``dynamics.dt: -1.0 is out of range, allowed (0, 1]``). The prefix of the key is the class's
:attr:`Schema.PREFIX` (e.g. ``"dynamics."``), or the prefix :func:`from_dict` was given.

Users: the pipeline configuration (:mod:`recon.config`), the physics parameters
(:mod:`recon.params`) and the ``oprecon compare`` tolerances (:mod:`recon.cli.compare`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import re
import types
from collections.abc import Iterator, Mapping
from contextvars import ContextVar
from dataclasses import MISSING, field, fields, is_dataclass
from typing import Any, ClassVar, Union, get_args, get_origin, get_type_hints

from .errors import ConfigError, did_you_mean

#: A number in exponent notation without a dot (1e-4): YAML 1.1 reads it as a string.
_EXPONENT_FLOAT = re.compile(r"[-+]?[0-9]+[eE][-+]?[0-9]+")

__all__ = ["Schema", "check_range", "coerce", "from_dict", "option", "range_text"]

#: Key prefix used by ``Schema.__post_init__`` while :func:`from_dict` builds an object.
_PREFIX: ContextVar[str | None] = ContextVar("recon_schema_prefix", default=None)


def option(
    default: Any = MISSING,
    doc: str = "",
    lo: float | None = None,
    hi: float | None = None,
    choices: tuple[Any, ...] | None = None,
    lo_open: bool = False,
) -> Any:
    """A dataclass field with documentation and an allowed range.

    Parameters
    ----------
    default : any, optional
        Default value (lists and dicts are copied per instance); omitted = a required field.
    doc : str
        One line shown by ``oprecon config show`` and in ``configs/default.yaml``.
    lo, hi : float, optional
        Inclusive bounds of a number (or of every item of a list of numbers).
    choices : tuple, optional
        The allowed values.
    lo_open : bool
        The lower bound is exclusive.
    """
    meta = {"doc": doc, "min": lo, "max": hi, "choices": choices, "min_open": lo_open}
    if default is MISSING:
        return field(metadata=meta)
    if isinstance(default, (list, dict)):
        return field(default_factory=lambda d=default: type(d)(d), metadata=meta)
    return field(default=default, metadata=meta)


#: How a message names a value of each plain type (``expected an integer, got ...``).
_EXPECTED = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


def _type_name(tp: Any) -> str:
    return getattr(tp, "__name__", str(tp)).replace("NoneType", "null")


def coerce(key: str, value: Any, tp: Any) -> Any:
    """Check ``value`` against the annotation ``tp``; return it converted (int -> float ok).

    A union of several types (``str | int | None``) takes the value as the first of them that
    accepts it.

    Raises
    ------
    ConfigError
        Naming ``key`` and the expected type.
    """
    origin = get_origin(tp)
    args = get_args(tp)
    if origin is Union or origin is types.UnionType:
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return coerce(key, value, inner[0])
        for alternative in inner:  # e.g. a size: str | int, the first that takes the value
            with contextlib.suppress(ConfigError):
                return coerce(key, value, alternative)
        expected = " or ".join(_EXPECTED.get(a, _type_name(a)) for a in inner)
        raise ConfigError(f"{key}: expected {expected}, got {value!r}")
    if value is None:
        raise ConfigError(f"{key}: null is not allowed (expected {_type_name(tp)})")
    if origin is list:
        (item_tp,) = args or (Any,)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{key}: expected a list, got {type(value).__name__} {value!r}")
        return [coerce(f"{key}[{i}]", v, item_tp) for i, v in enumerate(value)]
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true or false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return int(value)
    if tp is float:
        if isinstance(value, str) and _EXPONENT_FLOAT.fullmatch(value.strip()):
            value = float(value)  # YAML 1.1 reads 1e-4 (no dot) as a string
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"{key}: expected a finite number, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        return value
    return value


def _bounds_text(meta: Mapping[str, Any]) -> str:
    lo, hi = meta.get("min"), meta.get("max")
    # an unbounded side is open: values must be finite (``inf`` is refused)
    lo_s = "(-inf" if lo is None else f"{'(' if meta.get('min_open') else '['}{lo:g}"
    hi_s = "inf)" if hi is None else f"{hi:g}]"
    return f"{lo_s}, {hi_s}"


def check_range(key: str, value: Any, meta: Mapping[str, Any]) -> None:
    """Check a coerced value against the ``choices`` and bounds of its :func:`option`.

    Raises
    ------
    ConfigError
        ``key: value is not one of: ...`` (with the closest choice) or
        ``key: value is out of range, allowed [lo, hi]``.
    """
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        allowed = ", ".join(map(str, choices))
        raise ConfigError(
            f"{key}: {value!r} is not one of: {allowed}"
            f"{did_you_mean(str(value), list(map(str, choices)))}"
        )
    values = value if isinstance(value, list) else [value]
    lo, hi, lo_open = meta.get("min"), meta.get("max"), meta.get("min_open", False)
    for v in values:
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            continue
        bad = (lo is not None and (v < lo or (lo_open and v == lo))) or (hi is not None and v > hi)
        if bad:
            raise ConfigError(f"{key}: {v!r} is out of range, allowed {_bounds_text(meta)}")


def range_text(meta: Mapping[str, Any]) -> str:
    """`` Range [lo, hi].`` for documentation, or an empty string (choices, no bounds)."""
    if meta.get("choices"):
        return ""
    if meta.get("min") is None and meta.get("max") is None:
        return ""
    return f" Range {_bounds_text(meta)}."


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return get_type_hints(cls)


@contextlib.contextmanager
def _key_prefix(prefix: str) -> Iterator[None]:
    token = _PREFIX.set(prefix)
    try:
        yield
    finally:
        _PREFIX.reset(token)


class Schema:
    """Base of the validated frozen dataclasses (see the module docstring).

    Subclasses are ``@dataclass(frozen=True)`` with fields from :func:`option`; nested schema
    fields must hold instances of their annotated class. Override :meth:`check` for constraints
    that involve several fields.
    """

    #: Dotted prefix of this schema's keys in error messages, e.g. ``"dynamics."``.
    PREFIX: ClassVar[str] = ""

    def __post_init__(self) -> None:
        prefix = _PREFIX.get()
        prefix = self.PREFIX if prefix is None else prefix
        hints = _hints(type(self))
        for f in fields(self):  # type: ignore[arg-type]
            key = prefix + f.name
            tp = hints[f.name]
            value = getattr(self, f.name)
            if is_dataclass(tp):
                if not isinstance(value, tp):
                    raise ConfigError(
                        f"{key}: expected a {tp.__name__} section, got {type(value).__name__}"
                    )
                continue
            value = coerce(key, value, tp)
            if value is not None:
                check_range(key, value, f.metadata)
            object.__setattr__(self, f.name, value)
        self.check(prefix)

    def check(self, prefix: str) -> None:
        """Constraints that involve more than one field (``prefix`` starts every key named)."""


def from_dict(cls: type, data: Any, prefix: str = "") -> Any:
    """Build and validate the schema ``cls`` from a (YAML-like) mapping.

    Parameters
    ----------
    cls : type
        A :class:`Schema` dataclass; nested schema fields are built from nested mappings (a
        ``null`` section means its defaults).
    data : mapping
        Keys are field names; missing keys keep their defaults.
    prefix : str
        Dotted prefix of the keys in error messages (``"dynamics."``).

    Raises
    ------
    ConfigError
        Not a mapping, an unknown key (with the closest valid key), a wrong type, a value out
        of range, or a cross-field constraint; the message names the dotted key.
    """
    if not isinstance(data, Mapping):
        where = prefix.rstrip(".") or "configuration"
        raise ConfigError(f"{where}: expected a mapping of keys to values, got {data!r}")
    hints = _hints(cls)
    known = {f.name: f for f in fields(cls)}
    for k in data:
        if not isinstance(k, str) or k not in known:
            raise ConfigError(f"unknown key '{prefix}{k}'{did_you_mean(str(k), list(known))}")
    kwargs: dict[str, Any] = {}
    for name, value in data.items():
        key = prefix + name
        tp = hints[name]
        if is_dataclass(tp):
            kwargs[name] = from_dict(tp, value if value is not None else {}, key + ".")
            continue
        value = coerce(key, value, tp)
        if value is not None:
            check_range(key, value, known[name].metadata)
        kwargs[name] = value
    with _key_prefix(prefix):
        return cls(**kwargs)


def to_dict(obj: Any) -> dict[str, Any]:
    """Plain nested dict of a schema object (lists copied), suitable for YAML/JSON."""
    return dataclasses.asdict(obj)
