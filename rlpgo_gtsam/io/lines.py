"""The text of a g2o file: its lines, their fields, and fields read as ids and numbers.

Two ways to read the same text, which agree on every line they both take:

- line by line (:func:`numbered_lines`, :func:`line_records`), with every check a careful
  reader needs to name a bad line: the length of a line (:data:`MAX_LINE_BYTES`), NUL
  bytes, UTF-8, a stray CR; and tokens parsed one at a time (:func:`parse_id`,
  :func:`parse_numbers`, :func:`parse_fix`), each error naming the file and the line;
- a block at a time (:func:`blocks`, :class:`Text`): numpy finds the lines and fields of a
  few megabytes at once, and reads fields as ids and numbers exactly as ``int()`` and
  ``float()`` read them. Each reading method only ever accepts: where a field is not what it
  expects it returns None, and the caller hands the text to the careful reader.

A :class:`Text` splits fields at bytes up to 32 (space, tab, CR and the other control
characters); ``str.split`` splits at some control characters and not others, and at
non-ASCII spaces, so callers read with a :class:`Text` only the lines that hold
:data:`PLAIN` bytes alone (:meth:`Text.plain_lines`), where both agree; other lines are
split by ``str.split``, as the careful reader splits them (:func:`plain_keys`,
:func:`plain_numbers`).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO, Protocol

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from rlpgo_gtsam.errors import G2oFormatError, InputNotFoundError

__all__ = ["MAX_LINE_BYTES", "LineSource", "Text", "PLAIN", "BOM", "blocks", "open_g2o",
           "numbered_lines", "line_records", "short_token", "parse_id", "parse_numbers",
           "parse_fix", "plain_keys", "plain_numbers", "format_15", "texts_15",
           "upper_triangle_texts", "distinct_rows"]

# The longest line a reader takes: an EDGE_SE3:QUAT line with 64-bit ids and 30 numbers
# written with 17 significant digits is under 1 KiB; 64 KiB leaves room for any comment.
MAX_LINE_BYTES = 65536
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


# --------------------------------------------------------------------------- line by line


class LineSource(Protocol):
    """What the careful reader reads: an open binary file, or anything with its
    ``readline``."""

    def readline(self, size: int = -1, /) -> bytes: ...


def open_g2o(path: Path, kind: str = "g2o") -> BinaryIO:
    """``path`` opened for reading (binary), or the one-line error that says why not;
    ``kind`` names the format the messages expect (``"g2o"``, ``"PyFG"``)."""
    try:
        handle = path.open("rb")
    except FileNotFoundError:
        raise InputNotFoundError(path) from None
    except IsADirectoryError:
        raise G2oFormatError(path, None, f"is a directory, not a {kind} file") from None
    except PermissionError:
        raise G2oFormatError(path, None, "permission denied") from None
    if path.is_dir():
        handle.close()
        raise G2oFormatError(path, None, f"is a directory, not a {kind} file")
    return handle


def numbered_lines(path: Path, handle: LineSource | None = None,
                   kind: str = "g2o") -> Iterator[tuple[int, str]]:
    """(line number, text) of each line of the file at ``path`` (read from ``handle`` where
    given), with the careful reader's checks (line length, NUL bytes, UTF-8, a byte-order
    mark): what :func:`line_records` reads. ``kind`` names the format in the messages."""
    if handle is not None:
        yield from _lines(path, handle, kind)
        return
    with open_g2o(path, kind) as opened:
        yield from _lines(path, opened, kind)


def line_records(path: Path, handle: LineSource | None = None, kind: str = "g2o"
                 ) -> Iterator[tuple[int, str, list[str]]]:
    """(line number, tag, fields) of each line of :func:`numbered_lines` that is neither
    blank nor a comment: what the careful readers (g2o, PyFG) and
    :func:`~rlpgo_gtsam.io.file_group` read."""
    for number, text in numbered_lines(path, handle, kind):
        tokens = text.split()
        if tokens and not tokens[0].startswith("#"):
            yield number, tokens[0], tokens[1:]


def _lines(path: Path, handle: LineSource, kind: str) -> Iterator[tuple[int, str]]:
    number = 0
    while True:
        # readline with a limit: a file without newlines (/dev/zero, a huge sparse file)
        # costs at most MAX_LINE_BYTES of memory before it is refused.
        raw = handle.readline(MAX_LINE_BYTES + 1)
        if not raw:
            return
        number += 1
        if len(raw) > MAX_LINE_BYTES:
            if b"\r" in raw and b"\n" not in raw:
                raise G2oFormatError(path, number, "lines end in CR alone (classic Mac "
                                     "line endings); convert them to LF or CR LF")
            raise G2oFormatError(path, number,
                                 f"line longer than {MAX_LINE_BYTES} bytes (not a {kind} file?)")
        if b"\r" in raw.rstrip(b"\r\n") and raw.strip():  # a blank line's stray CR: blank
            raise G2oFormatError(path, number, "a CR inside a line (classic Mac line "
                                 "endings?); convert them to LF or CR LF")
        if number == 1 and raw.startswith(BOM):
            raw = raw[len(BOM):]
        if b"\x00" in raw:
            raise G2oFormatError(path, number, f"binary data, not a {kind} text file")
        try:
            yield number, raw.decode("utf-8")
        except UnicodeDecodeError:
            raise G2oFormatError(path, number, "not UTF-8 text (binary file?)") from None


def short_token(token: str, limit: int = 40) -> str:
    """``token`` as a message shows it: escaped, and cut at ``limit`` characters."""
    printable = token.encode("unicode_escape").decode("ascii")
    return printable if len(printable) <= limit else printable[:limit] + "..."


def parse_id(path: Path, line: int, token: str) -> int:
    """The vertex id ``token`` (a GTSAM key), or the error naming the line."""
    if not token.isascii() or not token.isdigit():
        raise G2oFormatError(
            path, line, f"vertex id must be a non-negative integer, found '{short_token(token)}'"
        )
    # GTSAM keys are 64-bit; the length test first keeps int() off huge digit strings.
    if len(token.lstrip("0")) > 20 or int(token) >= 2**64:
        raise G2oFormatError(path, line, f"vertex id {short_token(token)} is too large")
    return int(token)


def parse_numbers(path: Path, line: int, tag: str, tokens: list[str], first: int) -> list[float]:
    """Parse ``tokens`` as floats; ``first`` is the position of tokens[0] after the tag."""
    numbers = []
    for position, token in enumerate(tokens, start=first):
        try:
            if not token.isascii() or "_" in token:  # float() takes '1_0' and other digits
                raise ValueError(token)
            number = float(token)
        except ValueError:
            raise G2oFormatError(
                path, line, f"{tag} field {position} is not a number: '{short_token(token)}'"
            ) from None
        if not math.isfinite(number):
            raise G2oFormatError(path, line, f"{tag} field {position} is not finite: '{token}'")
        numbers.append(number)
    return numbers


def parse_fix(path: Path, line: int, fields: list[str]) -> list[tuple[int, int]]:
    """(id, line) of each id of a ``FIX`` line."""
    if not fields:
        raise G2oFormatError(path, line, "FIX needs at least one vertex id")
    return [(parse_id(path, line, field), line) for field in fields]


def plain_keys(tokens: list[str]) -> list[int] | None:
    """The ids, if every token is ASCII digits for a value below 2**64 (no leading zeros
    beyond 20 digits); None otherwise (the careful reader then judges them): the fast
    reader's ids on lines it splits as the careful reader does."""
    joined = "".join(tokens)
    if not (joined.isascii() and joined.isdigit()) or max(map(len, tokens)) > _ID_DIGITS:
        return None
    keys = list(map(int, tokens))
    return keys if max(keys) < 2**64 else None


def plain_numbers(tokens: list[str]) -> np.ndarray | None:
    """The tokens as finite floats, if every one is an ASCII number without '_' (what the
    careful reader takes); None otherwise."""
    joined = "".join(tokens)
    if not joined.isascii() or "_" in joined:
        return None
    try:
        numbers = np.array(list(map(float, tokens)))
    except ValueError:
        return None
    return numbers if np.isfinite(numbers).all() else None


# --------------------------------------------------------------------------- numbers as text


def format_15(value: float) -> str:
    # GTSAM stores an angle as (cos, sin) and a noise model as its square-root information,
    # so theta() and R^T R come back within an ulp or so of what was read. Fifteen
    # significant digits undo that: a file's own decimals come back unchanged, and
    # write -> read -> write gives the same text.
    return repr(float(f"{value:.15g}"))


def texts_15(values: list[float]) -> list[str]:
    """:func:`format_15` of each value, with one formatting call for them all.

    For a normal double, ``'%.15g'`` writes the digits that ``repr`` writes of the double
    those digits name (any two decimals of 15 significant digits are distinct doubles, so
    none shorter names it), in the same style (an exponent below 1e-4) but for two things:
    ``repr`` adds '.0' to a whole number, and writes 1e15 .. 1e16 in full. Values from 1e15
    on (or rounded up to it) and subnormal ones are written by :func:`format_15` itself.
    """
    texts = (("%.15g " * len(values)) % tuple(values)).split()
    return [(text if "." in text or "e" in text else text + ".0")
            if value == 0 or (1e-300 < abs(value) < 1e15 and "e+15" not in text)
            else format_15(value) for text, value in zip(texts, values, strict=True)]


def upper_triangle_texts(matrices: np.ndarray, size: int) -> list[str]:
    """The g2o fields of each ``size`` x ``size`` matrix of the stack: its upper triangle row
    by row, each number by :func:`format_15`, all formatted in one call."""
    upper = matrices[:, np.triu_indices(size)[0], np.triu_indices(size)[1]]
    numbers = texts_15(upper.ravel().tolist())
    width = upper.shape[1]
    return [" ".join(numbers[k * width:(k + 1) * width]) for k in range(len(upper))]


def distinct_rows(array: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of ``array`` (one row per leading index), told apart by their
    bytes: where each first appears (in the order they first appear) and, for each row,
    its index among them. One matrix for every row, the usual file's, is found without a
    sort."""
    flat = np.ascontiguousarray(array).reshape(len(array), -1)
    rows = flat.view(np.dtype((np.void, flat.shape[1] * flat.itemsize))).ravel()
    if len(rows) and (rows == rows[0]).all():
        return np.zeros(1, np.int64), np.zeros(len(rows), np.int64)
    # the rows' bytes as unsigned words, sorted stably (np.unique would do the same, but
    # numpy 2.4's imports numpy.ma for it: 4.5 ms of a command on MIT, Intel or FR079)
    words = np.ascontiguousarray(flat.view(np.uint8)).reshape(len(flat), -1)
    if words.shape[1] % 8 == 0:
        words = words.view(np.uint64)
    order = np.lexsort(words.T[::-1]) if words.shape[1] else np.arange(len(words))
    ordered = words[order]
    new = np.ones(len(order), bool)
    new[1:] = (ordered[1:] != ordered[:-1]).any(axis=1)
    first = order[new]  # stable: each group's first row in the file
    inverse = np.empty(len(order), np.int64)
    inverse[order] = np.cumsum(new) - 1
    rank = np.argsort(first)
    return first[rank], np.argsort(rank)[inverse]
