"""Plain text as arrays: its lines, their whitespace-separated fields, and fields read as ids
and numbers exactly as ``int()`` and ``float()`` read them.

The fast g2o readers (:mod:`rlpgo_gtsam.g2o`, :mod:`rlpgo_gtsam.g2o3d`) parse a few megabytes
at a time with these: numpy finds the lines and fields of the whole block, the records are
checked and gathered column by column, and only the numbers themselves go through
``float()`` (numpy reads ids). Each reading method only ever accepts: where a field is not
what it expects it returns None, and the caller hands the text to its careful, line-by-line
reader, which names the bad line.

A :class:`Text` splits fields at bytes up to 32 (space, tab, CR and the other control
characters); ``str.split`` splits at some control characters and not others, and at
non-ASCII spaces, so callers read with a :class:`Text` only the lines that hold
:data:`PLAIN` bytes alone (:meth:`Text.plain_lines`), where both agree.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from typing import BinaryIO

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

__all__ = ["Text", "PLAIN", "BOM", "blocks"]

# The bytes of the lines a Text reads: printable ASCII, tab, CR (and LF, which ends a line).
PLAIN = bytes(range(32, 127)) + b"\t\r\n"
_ID_DIGITS = 20  # 2**64 - 1 has 20 digits
_WIDEST_SPAN = 512  # bytes: same_text compares longer spans as Python bytes
_SPAN_BYTES = 1 << 22  # same_text compares at most this many bytes at once
_BATCH = 1 << 16  # ids read at once: a few MB of work arrays whatever the text
_PAD = max(_ID_DIGITS, _WIDEST_SPAN)
BOM = b"\xef\xbb\xbf"  # a UTF-8 byte-order mark, skipped at the start of a text


def blocks(handle: BinaryIO, chunk_bytes: int, longest_line: int) -> Iterator[Text | None]:
    """The text of ``handle`` a block of whole lines at a time (about ``chunk_bytes`` each),
    a UTF-8 byte-order mark at its start left out; None for a block that only a careful,
    line-by-line reader should judge: one with a line longer than ``longest_line`` bytes, a
    NUL byte, bytes that are not UTF-8, or a CR that does not end a line.

    Memory: one block and its arrays at a time.
    """
    pending = b""  # the unfinished last line of the previous block
    first = True
    while True:
        chunk = handle.read(chunk_bytes)
        data = pending + chunk
        if chunk:
            cut = data.rfind(b"\n") + 1
            data, pending = data[:cut], data[cut:]
            if len(pending) > longest_line:
                yield None
                return
        if first and data.startswith(BOM):
            data = data[len(BOM):]
        first = first and not data
        if data:
            yield _block(data, longest_line)
        if not chunk:
            return


def _block(data: bytes, longest_line: int) -> Text | None:
    if b"\r" in data and data.count(b"\r") != data.count(b"\r\n"):
        return None  # a CR that does not end a line
    text = Text(data)
    if not text.is_plain():
        if b"\x00" in data:
            return None  # binary data
        try:
            data.decode("utf-8")
        except UnicodeDecodeError:
            return None
    return text if text.longest_line() <= longest_line else None


class Text:
    """A block of text as arrays: where each line and each of its fields begins and ends.

    Attributes:
        data: the text (bytes); lines end in LF, the last one may not.
        starts, ends: (lines,) offset of each line's first byte and of its end (its LF, or
            the end of the text).
        field_starts, field_ends: (fields,) offsets of each field, in text order (a field is
            a run of bytes above 32).
        first, count: (lines,) index of each line's first field, and how many it has.
    """

    def __init__(self, data: bytes) -> None:
        self.data = data
        # padded with spaces: a window of up to _PAD bytes from any field stays inside
        self._buffer = np.frombuffer(data + b" " * _PAD, np.uint8)
        text = self._buffer[:len(data)]
        ends = np.flatnonzero(text == 10)
        if not data.endswith(b"\n"):
            ends = np.append(ends, len(data))
        self.ends = ends
        self.starts = np.concatenate(([0], ends[:-1] + 1))
        # field boundaries: where "is a space" flips (a space before and after the text)
        flips = np.flatnonzero(np.diff(text <= 32, prepend=True, append=True))
        self.field_starts, self.field_ends = flips[0::2], flips[1::2]
        self.first = np.searchsorted(self.field_starts, self.starts)
        self.count = np.searchsorted(self.field_starts, self.ends) - self.first
        self._plain: bool | None = None

    def __len__(self) -> int:
        return len(self.starts)

    def longest_line(self) -> int:
        """The length in bytes of the longest line, its LF included."""
        return int((self.ends - self.starts).max(initial=-1)) + 1

    def is_plain(self) -> bool:
        """Whether the whole text is :data:`PLAIN` bytes."""
        if self._plain is None:
            self._plain = not self.data.translate(None, PLAIN)
        return self._plain

    def plain_lines(self) -> np.ndarray:
        """(lines,) bool: the lines that hold :data:`PLAIN` bytes alone."""
        plain = np.ones(len(self), bool)
        if not self.is_plain():  # some byte is not plain: find its lines
            odd = np.ones(256, bool)
            odd[np.frombuffer(PLAIN, np.uint8)] = False
            where = np.flatnonzero(odd[self._buffer[:len(self.data)]])
            plain[np.searchsorted(self.ends, where)] = False
        return plain

    def first_field_is(self, word: bytes) -> np.ndarray:
        """(lines,) bool: the lines whose first field is ``word`` (at most 512 bytes)."""
        has = np.flatnonzero(self.count > 0)
        starts = self.field_starts[self.first[has]]
        match = self.field_ends[self.first[has]] - starts == len(word)
        window = sliding_window_view(self._buffer, len(word))
        match &= (window[starts] == np.frombuffer(word, np.uint8)).all(axis=1)
        result = np.zeros(len(self), bool)
        result[has] = match
        return result

    def first_byte(self) -> np.ndarray:
        """(lines,) the first byte of each line's first field; 0 for a blank line."""
        result = np.zeros(len(self), np.uint8)
        has = self.count > 0
        result[has] = self._buffer[self.field_starts[self.first[has]]]
        return result

    def fields(self, lines: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
        """(k, count) starts and ends of the first ``count`` fields of each of ``lines``."""
        index = self.first[lines][:, None] + np.arange(count)
        return self.field_starts[index], self.field_ends[index]

    def line(self, line: int) -> bytes:
        """The bytes of one line, without its LF."""
        return self.data[self.starts[line]:self.ends[line]]

    def spans(self, starts: np.ndarray, ends: np.ndarray) -> list[bytes]:
        """The bytes ``data[starts[k]:ends[k]]`` of each span."""
        data = self.data
        return [data[s:e] for s, e in zip(starts.tolist(), ends.tolist(), strict=True)]

    def joined(self, starts: np.ndarray, ends: np.ndarray) -> bytes:
        """The spans ``data[starts[k]:ends[k]]`` (ascending, apart, each ending where a field
        ends) as one text, each followed by the whitespace byte that ends it: what
        ``b" ".join(self.spans(starts, ends))`` holds to ``np.fromstring(..., sep=" ")``.
        Where the spans cover much of the text, numpy gathers their bytes at once (a third
        of the time of a bytes object per span)."""
        if 8 * int((ends - starts).sum(initial=0)) < len(self.data):
            return b" ".join(self.spans(starts, ends))
        size = len(self.data) + 1  # the byte after the last span may be the padding
        edges = np.zeros(size + 1, np.int8)
        edges[starts] = 1
        edges[ends + 1] -= 1
        inside = np.cumsum(edges[:size], dtype=np.int8).view(bool)
        return self._buffer[:size][inside].tobytes()

    def lines_text(self, lines: np.ndarray) -> bytes:
        """The given lines (ascending), each with its LF, as one block of text."""
        if not len(lines):
            return b""
        starts, ends = self.starts[lines], self.ends[lines] + 1
        if lines[-1] - lines[0] == len(lines) - 1:  # one run of lines: one slice
            return self.data[starts[0]:ends[-1]]
        return b"".join(self.spans(starts, ends))

    # ----------------------------------------------------------------------- fields as values

    def ids(self, starts: np.ndarray, ends: np.ndarray) -> np.ndarray | None:
        """The fields as uint64 ids; None unless each is ASCII digits (at most 20) for a
        value below 2**64."""
        lengths = ends - starts
        if not len(starts):
            return np.zeros(0, np.uint64)
        if lengths.max() > _ID_DIGITS:
            return None
        result = np.empty(len(starts), np.uint64)
        for part in range(0, len(starts), _BATCH):
            values = self._ids(starts[part:part + _BATCH], lengths[part:part + _BATCH])
            if values is None:
                return None
            result[part:part + _BATCH] = values
        return result

    def _ids(self, starts: np.ndarray, lengths: np.ndarray) -> np.ndarray | None:
        width = int(lengths.max())
        digits = sliding_window_view(self._buffer, width)[starts] - np.uint8(48)
        inside = np.arange(width) < lengths[:, None]
        if not (digits < 10)[inside].all():  # a byte below '0' wraps above 9
            return None
        values = np.zeros(len(starts), np.uint64)
        ten = np.uint64(10)
        for column in range(min(width, _ID_DIGITS - 1)):  # 19 digits stay below 2**64
            values = np.where(inside[:, column], values * ten + digits[:, column], values)
        longest = np.flatnonzero(lengths == _ID_DIGITS)
        if len(longest):  # 20 digits: Python's int tells which are below 2**64
            exact = list(map(int, self.spans(starts[longest], starts[longest] + _ID_DIGITS)))
            if max(exact) >= 2**64:
                return None
            values[longest] = exact
        return values

    def records(self, lines: np.ndarray, width: int, ids: int,
                numbers: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The records on ``lines`` (plain lines) of a tag and ``width - 1`` fields: (k, ids)
        the ids in the fields after the tag, (k, numbers) the numbers in the fields after
        those; None if a line has another number of fields, or one of these fields is not
        what :meth:`ids` or :meth:`numbers` takes."""
        if (self.count[lines] != width).any():
            return None
        index = (self.first[lines][:, None] + np.arange(1, ids + 1)).ravel()
        keys = self.ids(self.field_starts[index], self.field_ends[index])
        values = self.numbers(lines, ids + 1, numbers)
        if keys is None or values is None:
            return None
        return keys.reshape(len(lines), ids), values

    def numbers(self, lines: np.ndarray, first: int, count: int) -> np.ndarray | None:
        """(k, count) fields ``first .. first + count - 1`` of each of ``lines`` (plain lines
        with that many fields) as float64, each exactly ``float(field)``; None unless every
        one is a finite number without '_' (the careful reader's rule)."""
        if not len(lines):
            return np.zeros((0, count))
        index = self.first[lines] + first
        block = self.joined(self.field_starts[index], self.field_ends[index + count - 1])
        if b"_" in block:  # float() takes '1_0'; the careful reader does not
            return None
        numbers = _floats(block)
        if numbers is None or len(numbers) != len(lines) * count or not np.isfinite(numbers).all():
            return None
        return numbers.reshape(len(lines), count)

    def same_text(self, starts: np.ndarray, ends: np.ndarray) -> bool:
        """Whether the spans ``[starts, ends)`` all hold the same bytes (the usual g2o file:
        one information matrix for every edge, written the same way)."""
        lengths = ends - starts
        if not len(starts) or (lengths != lengths[0]).any():
            return False
        if lengths[0] > _WIDEST_SPAN:
            return len(set(self.spans(starts, ends))) == 1
        window = sliding_window_view(self._buffer, int(lengths[0]))
        first = window[starts[0]]
        rows = max(1, _SPAN_BYTES // max(1, int(lengths[0])))
        return all(bool((window[starts[k:k + rows]] == first).all())
                   for k in range(0, len(starts), rows))


def _floats(block: bytes) -> np.ndarray | None:
    """The whitespace-separated numbers of ``block`` (ASCII), each read as ``float()`` reads
    it, or None where one is not a number.

    ``np.fromstring`` reads each with ``PyOS_string_to_double``, as ``float()`` does, without
    a Python object per number. It reads a field as far as a number goes and the next from
    there, separators being optional ('1.5.5' is 1.5 and .5), and stops with an error at
    anything that is no number (a DeprecationWarning in older numpy, made an error here): so
    as many numbers as fields means that each field was one number, whole.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        try:
            return np.fromstring(block, dtype=np.float64, sep=" ")
        except (ValueError, DeprecationWarning):
            return None
