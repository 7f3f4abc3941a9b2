"""The input contract of the reports: the results and floor frames, checked once.

``results`` has one row per (shape, method, seed) job with the columns of
:mod:`foundation.schema` (``shape, method, seed, status ('ok'|'failed'), error``, raw metric
columns ``cd, nc, f1_<tau>, ecd, ef1``, the flags ``empty_prediction`` and ``ecd_flag``, the
validity columns and wall-clock seconds in columns ending in ``_s``) plus any extra metric or timing
columns a preset or a method adds. ``floor`` has one row per shape with the same metric columns:
the GT against an independent resample of itself. Metric values are raw: tables
apply the preset's multipliers. Rows with ``scored`` 0 are shapes without a GT (a point cloud given
alone): their meshes and validity counts are reported, never their (absent) metrics.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

REQUIRED = ("shape", "method", "seed", "status", "error")


def check_results(results, what: str = "results") -> pd.DataFrame:
    """A copy of the results frame with ``shape`` and ``method`` as text.

    Raises
    ------
    ValueError
        One line, when ``results`` is not a DataFrame or lacks a column of :data:`REQUIRED`.
    """
    if not isinstance(results, pd.DataFrame):
        raise ValueError(f"{what} must be a pandas DataFrame, got {type(results).__name__}")
    missing = [c for c in REQUIRED if c not in results.columns]
    if missing:
        raise ValueError(f"{what} frame lacks column(s) {', '.join(missing)}")
    df = results.copy()
    df["shape"] = df["shape"].astype(str)
    df["method"] = df["method"].astype(str)
    return df


def check_floor(floor) -> pd.DataFrame | None:
    """The floor rows that were computed (status 'ok' when the frame has a status), shape as text;
    None when there are none."""
    if floor is None:
        return None
    if not isinstance(floor, pd.DataFrame):
        raise ValueError(f"floor must be a pandas DataFrame or None, got {type(floor).__name__}")
    df = floor.copy()
    if "shape" in df.columns:
        df["shape"] = df["shape"].astype(str)
    if "status" in df.columns:  # a floor row that could not be computed is not a reference
        df = df[df["status"] == "ok"]
    df = df[scored(df)]  # a shape without a GT has no floor
    return df if len(df) else None


def ok_jobs(results: pd.DataFrame) -> pd.DataFrame:
    """The successful jobs (status 'ok')."""
    return results[results["status"] == "ok"]


def scored(frame: pd.DataFrame) -> pd.Series:
    """Per row: scored against a GT (the ``scored`` column; False only for a shape without a GT, a
    point cloud given alone; a frame without the column: every row scored)."""
    if "scored" not in frame.columns:
        return pd.Series(True, index=frame.index)
    return pd.to_numeric(frame["scored"], errors="coerce").fillna(1) > 0.5


def without_unscored(results: pd.DataFrame) -> pd.DataFrame:
    """The rows the metric tables aggregate: every job but the successful ones without a GT (failed
    jobs stay: they are counted)."""
    return results[(results["status"] != "ok") | scored(results)]


def unscored_jobs(results: pd.DataFrame) -> pd.DataFrame:
    """The successful jobs of shapes without a GT: reconstructed, not scored."""
    return results[(results["status"] == "ok") & ~scored(results)]


def numeric(frame: pd.DataFrame, column: str) -> pd.Series:
    """``frame[column]`` as float (NaN where not a number); all NaN when the column is absent."""
    if column not in frame.columns:
        return pd.Series(np.nan, index=frame.index, dtype=float)
    return pd.to_numeric(frame[column], errors="coerce").astype(float)


def as_bool(values: pd.Series) -> pd.Series:
    """A 0/1 or bool column (SQLite stores flags as integers) as bool; NaN -> False."""
    return pd.to_numeric(values, errors="coerce").fillna(0) > 0.5


def sensors_note(results: pd.DataFrame) -> str | None:
    """Which methods were given each input point's sensor position (``used_sensors``: the input was a
    scan and the method uses sensors), in one sentence; None when none was."""
    if "used_sensors" not in results.columns:
        return None
    used = list(dict.fromkeys(results.loc[as_bool(results["used_sensors"]), "method"]))
    if not used:
        return None
    return (f"Given each input point's sensor position (a scan): {', '.join(used)}; every other method got the "
            "points alone.")
