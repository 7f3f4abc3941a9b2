"""What the property-based tests of the loaders share (``tests/test_*`` import it; issue 41, item 2).

A loader given any bytes either returns a valid object or raises the project's own error with a
one-line message; :func:`loads_or_refuses` checks that contract for one call: no other exception type
(IndexError, UnicodeDecodeError, struct.error, MemoryError, ...), no line break in the message, no
warning and no log record of WARNING or above on the way, no file written beside the input, and a
bounded time (:data:`TIME_LIMIT_S`, a hang fails the test instead of stalling CI).

The strategies turn a valid file into the inputs a user might hand over: random bytes, the file
truncated at any offset, bytes flipped, inserted or deleted, a header count made huge, a number made
NaN or infinite, text in a wrong encoding. The example counts come from the Hypothesis profile
(``tests/conftest.py``: "fast" by default, ``SALSBENCH_HYPOTHESIS=slow`` for ten times as many).
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import tracemalloc
import warnings
from pathlib import Path
from typing import Any, Callable

from hypothesis import strategies as st

#: Seconds one load may take before the test fails as a hang (the profiles' deadline, 2 s, reports
#: slow examples; this stops a loop that never returns).
TIME_LIMIT_S = 20
#: Bytes a load of a small fuzzed file may allocate at its peak (traced): a header that claims
#: billions of elements must be refused before its arrays are allocated.
PEAK_BYTES = 64 * 2**20


class _Hang(BaseException):  # not an Exception: a loader's "except Exception" must not turn it into its error
    pass


@contextlib.contextmanager
def _time_limit(seconds: float):
    if not hasattr(signal, "SIGALRM"):  # not on this platform: the deadline still reports slow examples
        yield
        return

    def expire(*_):
        raise _Hang(f"a load ran longer than {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


class _Records(logging.Handler):
    def __init__(self):
        super().__init__(logging.WARNING)
        self.records: list[logging.LogRecord] = []

    def emit(self, record):
        self.records.append(record)


def loads_or_refuses(load: Callable[[Path], Any], path: Path, error: type[Exception] | tuple,
                     names_file: bool = True, trace_memory: bool = False) -> Any:
    """``load(path)``: its value, or None when it raised ``error`` with a one-line message (naming
    ``path`` when ``names_file``). Fails the test on any other exception, a warning or log record
    on the way, a file created in ``path``'s folder, a hang, or (``trace_memory``) a traced peak
    over :data:`PEAK_BYTES`."""
    folder = path.parent
    before = sorted(os.listdir(folder))
    handler = _Records()
    root = logging.getLogger()
    root.addHandler(handler)
    if trace_memory:
        tracemalloc.start()
    try:
        with warnings.catch_warnings(record=True) as caught, _time_limit(TIME_LIMIT_S):
            warnings.simplefilter("always")
            try:
                value = load(path)
            except error as exc:
                message, value = str(exc), None
                assert message and not re.search(r"[\r\n]", message), f"not one line: {message!r}"
                assert "MemoryError" not in message, f"allocated for a claimed size: {message}"
                if names_file:
                    assert str(path) in message, f"does not name the file: {message!r}"
    finally:
        peak = tracemalloc.get_traced_memory()[1] if trace_memory else 0
        if trace_memory:
            tracemalloc.stop()
        root.removeHandler(handler)
    shown = [w for w in caught if not issubclass(w.category, (DeprecationWarning, PendingDeprecationWarning))]
    assert not shown, f"a warning reached the user: {shown[0].category.__name__}: {shown[0].message}"
    assert not handler.records, f"a log record reached the user: {handler.records[0].getMessage()[:200]}"
    assert sorted(os.listdir(folder)) == before, "the load wrote beside its input"
    assert peak <= PEAK_BYTES, f"a load of {path.stat().st_size:,} bytes allocated {peak:,} bytes at its peak"
    return value


# -- strategies ---------------------------------------------------------------------------------

#: Numbers a header may claim: small, around the real ones, and far beyond any file.
COUNTS = st.one_of(st.integers(0, 20), st.sampled_from([999_999_999, 2**31 - 1, 2**32 - 1, 2**32, 2**63 - 1,
                                                        10**12, 10**20]))
#: Coordinates, NaN and infinities included.
FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)
#: Bytes text files should not hold: Latin-1 letters, lone UTF-8 continuation bytes, a BOM, NUL.
BAD_TEXT = st.sampled_from([b"\xe9", b"\x80\x81", b"\xff\xfe", b"\xef\xbb\xbf", b"\xc3(", b"\x00", b"\x85",
                            "é".encode("utf-16"), b"\r", b"\t", b"\x1a"])


@st.composite
def mutated(draw, valid: bytes, counts: list[tuple[bytes, bytes]] = (), numbers: list[bytes] = ()) -> bytes:
    """``valid`` changed one way or several: truncated, bytes flipped, inserted or deleted, a bad
    text byte inserted, a header count given as ``(old, template)`` in ``counts`` (``old`` replaced
    by ``template % count``) made huge or wrong, one of ``numbers`` replaced by NaN, inf or a huge
    exponent."""
    data = bytearray(valid)
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["truncate", "flip", "insert", "delete", "text", "count", "number"]))
        at = draw(st.integers(0, len(data)))
        if kind == "truncate":
            del data[at:]
        elif kind == "flip" and data:
            data[min(at, len(data) - 1)] = draw(st.integers(0, 255))
        elif kind == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=16))
        elif kind == "delete":
            del data[at:at + draw(st.integers(1, 16))]
        elif kind == "text":
            data[at:at] = draw(BAD_TEXT)
        elif kind == "count" and counts:
            old, template = draw(st.sampled_from(list(counts)))
            data = bytearray(bytes(data).replace(old, template % draw(COUNTS), 1))
        elif kind == "number" and numbers:
            old = draw(st.sampled_from(list(numbers)))
            new = draw(st.sampled_from([b"nan", b"inf", b"-inf", b"NaN", b"1e999", b"-1e400", b"1e-400", b"0x1p3"]))
            data = bytearray(bytes(data).replace(old, new, 1))
    return bytes(data)


def truncations(valid: bytes):
    """``valid`` cut at any offset, most often near where its parts end (a line, a header, the end)."""
    near_ends = [i for i, b in enumerate(valid) if b in b"\n\r"] + [len(valid) - 1]
    return st.one_of(st.integers(0, len(valid) - 1),
                     st.sampled_from(near_ends).flatmap(lambda i: st.integers(max(0, i - 2), i + 1))
                     ).map(lambda cut: valid[:min(cut, len(valid) - 1)])
