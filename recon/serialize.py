"""JSON serialisation of reports, summaries and manifests: the one encoder of the project.

Reports hold numpy scalars and arrays, paths and frozen dataclasses with ``to_dict()``;
:func:`json_default` turns each into plain JSON. :func:`dumps` writes the project's JSON layout
(one-space indent, a trailing newline is the caller's).

>>> import numpy as np
>>> dumps({"n": np.int64(3), "x": np.array([0.5, 1.0])})
'{\\n "n": 3,\\n "x": [\\n  0.5,\\n  1.0\\n ]\\n}'
>>> dumps({"bad": float("nan")}, strict=True)
'{\\n "bad": null\\n}'
"""

from __future__ import annotations

import json
import math
from pathlib import PurePath
from typing import Any

__all__ = ["dumps", "json_default", "replace_non_finite"]


def json_default(obj: Any) -> Any:
    """``default=`` hook for :func:`json.dumps`: numpy values, paths and report dataclasses."""
    import numpy as np  # here, not at the top: `oprecon --help` imports this module

    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, PurePath):
        return str(obj)
    to_dict = getattr(obj, "to_dict", None)
    if callable(to_dict):
        return to_dict()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def replace_non_finite(obj: Any) -> Any:
    """A copy of ``obj`` with NaN and infinities as ``None`` (strict JSON has no NaN)."""
    import numpy as np

    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {str(k): replace_non_finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [replace_non_finite(v) for v in obj]
    if isinstance(obj, (np.generic, np.ndarray, PurePath)) or callable(
        getattr(obj, "to_dict", None)
    ):
        return replace_non_finite(json_default(obj))
    return obj


def dumps(obj: Any, *, indent: int | None = 1, strict: bool = False, **kwargs: Any) -> str:
    """JSON text of ``obj``; ``strict`` writes non-finite floats as ``null`` instead of ``NaN``."""
    if strict:
        return json.dumps(replace_non_finite(obj), indent=indent, allow_nan=False, **kwargs)
    return json.dumps(obj, indent=indent, default=json_default, **kwargs)
