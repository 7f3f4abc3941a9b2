"""JSON for records, reports and the command line (the project's one sanitiser).

:func:`json_safe` turns numpy scalars and arrays, paths, tuples and dataclasses into plain JSON
values and non-finite floats (NaN, inf) into ``null``, so every JSON file the project writes is
valid JSON (``json.dumps`` would write the non-standard token ``NaN``).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import PurePath
from typing import Any

import numpy as np


def json_safe(value: Any) -> Any:
    """A JSON-ready copy of ``value`` (see module docstring); unknown objects become their ``repr``."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [json_safe(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(float(value)) else None
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, PurePath):
        return str(value)
    if value is None or isinstance(value, str):
        return value
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return json_safe(dataclasses.asdict(value))
    return repr(value)


def dumps(value: Any, **kwargs: Any) -> str:
    """``json.dumps(json_safe(value), sort_keys=True, allow_nan=False, **kwargs)``."""
    kwargs.setdefault("sort_keys", True)
    return json.dumps(json_safe(value), allow_nan=False, **kwargs)
