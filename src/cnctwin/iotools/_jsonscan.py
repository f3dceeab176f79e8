"""Structure scan of large JSON documents (private helper of the Capture4Analysis reader).

A Capture4Analysis file is one JSON object ``{"Header": {...}, "Payload": [...], "Footer": {...}}``
of up to 100 MB. Parsing it whole with :func:`orjson.loads` builds a Python object tree about four
times the size of the text (a ``float`` object plus a list slot per number). Instead,
:func:`scan_document` walks the bytes once (numba, no Python objects), and returns where each
top-level member and each element of a top-level array starts and ends. The caller then parses
one element at a time with orjson (zero-copy ``memoryview`` slices) and drops the objects at once.

The scan tracks strings (with backslash escapes) so brackets inside G-code text such as
``S[iAnr2]=rDrzahlWK[iToolNr,iSZpr]`` do not count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["ScanResult", "close_partial", "scan_document"]

# error codes of the scanner
ERR_NONE = 0
ERR_NOT_OBJECT = 1
ERR_MISMATCH = 2
ERR_TOO_DEEP = 3
ERR_TRAILING = 4
ERR_TOO_MANY_MEMBERS = 5
ERR_EMPTY = 6
ERR_CAPACITY = 7  # internal: rerun with more room for elements

ERROR_TEXT = {
    ERR_NOT_OBJECT: "the document is not a JSON object (expected '{' first)",
    ERR_MISMATCH: "a closing bracket does not match the open one",
    ERR_TOO_DEEP: "nesting deeper than 250 levels",
    ERR_TRAILING: "unexpected data after the end of the top-level object",
    ERR_TOO_MANY_MEMBERS: "more than 1000 top-level members",
    ERR_EMPTY: "the document is empty",
}

FLAG_STRING = 1
"""An element holds a string at depth >= 5 (an HF value given as a string)."""
FLAG_LITERAL = 2
"""An element holds a non-numeric token (``null``, ``true``, garbage) at depth >= 5."""


@dataclass
class ScanResult:
    """Where things are in the document (byte offsets; ends are exclusive).

    Attributes
    ----------
    members : ndarray, shape (m, 4)
        Per top-level member: key start, key end (inside the quotes), value start, value end
        (``-1`` if the value did not end: truncated input).
    elements : ndarray, shape (e, 5)
        Per element of a top-level array: member index, start, end, number of nested arrays at
        depth 5 (HF rows), flags (:data:`FLAG_STRING`, :data:`FLAG_LITERAL`).
    open_element_start : int
        Start of an element that never ended (truncated input), else -1.
    open_element_member : int
        Member index of that element, else -1.
    depth : int
        Nesting depth at the end of the input (0 for a complete document).
    in_string : bool
        Whether the input ends inside a string.
    error : int
        Error code (0: none).
    error_pos : int
        Byte offset of the error.
    """

    members: NDArray[np.int64]
    elements: NDArray[np.int64]
    open_element_start: int
    open_element_member: int
    depth: int
    in_string: bool
    error: int
    error_pos: int

    @property
    def complete(self) -> bool:
        """The document closed properly."""
        return self.error == ERR_NONE and self.depth == 0 and not self.in_string


def _byte_classes() -> NDArray[np.uint8]:
    """Byte -> class for the scanner: 0 number/whitespace (the common case), 1 ``,``,
    2 ``"``, 3 ``{``/``[``, 4 ``}``/``]``, 5 ``:``, 6 anything else."""
    cls = np.full(256, 6, dtype=np.uint8)
    for ch in b"0123456789+-.eE \t\r\n":
        cls[ch] = 0
    cls[ord(",")] = 1
    cls[ord('"')] = 2
    cls[ord("{")] = cls[ord("[")] = 3
    cls[ord("}")] = cls[ord("]")] = 4
    cls[ord(":")] = 5
    return cls


_CLASSES = _byte_classes()


def _scan_py(buf: NDArray[np.uint8], cls: NDArray[np.uint8], cap: int) -> tuple[
    NDArray[np.int64], NDArray[np.int64], int, int, int, int, int, int, int
]:  # pragma: no cover - compiled by numba; the Python body is the reference
    n = buf.size
    members = np.full((1000, 4), -1, dtype=np.int64)
    n_members = 0
    elems = np.zeros((cap, 5), dtype=np.int64)  # fixed: growing it in the loop costs 20x
    n_elems = 0
    stack = np.zeros(256, dtype=np.uint8)
    depth = 0
    str_start = -1
    last_key_start = -1
    last_key_end = -1
    elem_start = -1
    rows = 0
    flags = 0
    top_done = False
    top_end = -1
    i = 0
    # skip a UTF-8 byte order mark
    if n >= 3 and buf[0] == 0xEF and buf[1] == 0xBB and buf[2] == 0xBF:
        i = 3
    while i < n:
        c = cls[buf[i]]
        if c == 0:  # digits, sign, dot, exponent, whitespace: nothing to track
            i += 1
            continue
        if top_done:
            return (members[:n_members], elems[:n_elems], -1, -1, depth, 0, ERR_TRAILING, i,
                    top_end)
        if c == 1:  # ,
            if depth == 1:
                if n_members > 0:
                    members[n_members - 1, 3] = i
            elif depth == 2 and stack[2] == 2:
                if n_elems == cap:
                    return (members[:n_members], elems[:n_elems], -1, -1, depth, 0, ERR_CAPACITY,
                            i, top_end)
                elems[n_elems, 0] = n_members - 1
                elems[n_elems, 1] = elem_start
                elems[n_elems, 2] = i
                elems[n_elems, 3] = rows
                elems[n_elems, 4] = flags
                n_elems += 1
                elem_start = i + 1
                rows = 0
                flags = 0
        elif c == 2:  # a string: skip to its closing quote
            if depth == 0:
                return (members[:n_members], elems[:n_elems], -1, -1, 0, 0, ERR_NOT_OBJECT, i,
                        top_end)
            if depth >= 5:
                flags |= 1
            str_start = i
            i += 1
            closed = False
            while i < n:
                b = buf[i]
                if b == 92:  # backslash escapes the next byte
                    i += 2
                    continue
                if b == 34:
                    closed = True
                    break
                i += 1
            if not closed:
                open_start = elem_start if depth >= 2 and stack[2] == 2 else -1
                open_member = n_members - 1 if open_start >= 0 else -1
                return (members[:n_members], elems[:n_elems], open_start, open_member, depth,
                        1, ERR_NONE, -1, top_end)
            if depth == 1:
                last_key_start = str_start + 1
                last_key_end = i
        elif c == 3:  # { [
            b = buf[i]
            if depth == 0 and b != 123:
                return (members[:n_members], elems[:n_elems], -1, -1, 0, 0, ERR_NOT_OBJECT, i,
                        top_end)
            if depth >= 250:
                return (members[:n_members], elems[:n_elems], -1, -1, depth, 0, ERR_TOO_DEEP, i,
                        top_end)
            depth += 1
            stack[depth] = 1 if b == 123 else 2
            if depth == 5 and b == 91 and stack[4] == 2:
                rows += 1
            if depth == 2 and b == 91:
                elem_start = i + 1
                rows = 0
                flags = 0
        elif c == 4:  # } ]
            b = buf[i]
            expected = 1 if b == 125 else 2
            if depth == 0 or stack[depth] != expected:
                return (members[:n_members], elems[:n_elems], -1, -1, depth, 0, ERR_MISMATCH,
                        i, top_end)
            if depth == 2 and b == 93:
                # end of a top-level array: the last element ends here (if not empty)
                j = elem_start
                while j < i and (buf[j] == 32 or buf[j] == 10 or buf[j] == 13 or buf[j] == 9):
                    j += 1
                if j < i:
                    if n_elems == cap:
                        return (members[:n_members], elems[:n_elems], -1, -1, depth, 0,
                                ERR_CAPACITY, i, top_end)
                    elems[n_elems, 0] = n_members - 1
                    elems[n_elems, 1] = elem_start
                    elems[n_elems, 2] = i
                    elems[n_elems, 3] = rows
                    elems[n_elems, 4] = flags
                    n_elems += 1
                elem_start = -1
            if depth == 1:
                if n_members > 0:
                    members[n_members - 1, 3] = i
                top_done = True
                top_end = i
            depth -= 1
        elif c == 5:  # :
            if depth == 1:
                if n_members == 1000:
                    return (members[:n_members], elems[:n_elems], -1, -1, depth, 0,
                            ERR_TOO_MANY_MEMBERS, i, top_end)
                members[n_members, 0] = last_key_start
                members[n_members, 1] = last_key_end
                members[n_members, 2] = i + 1
                members[n_members, 3] = -1
                n_members += 1
        else:  # letters and other bytes outside strings (true, false, null, garbage)
            if depth == 0:
                return (members[:n_members], elems[:n_elems], -1, -1, 0, 0, ERR_NOT_OBJECT, i,
                        top_end)
            if depth >= 5:
                flags |= 2
        i += 1
    if not top_done and depth == 0:
        return (members[:n_members], elems[:n_elems], -1, -1, 0, 0, ERR_EMPTY, n, top_end)
    open_start = elem_start if depth >= 2 and stack[2] == 2 else -1
    open_member = n_members - 1 if open_start >= 0 else -1
    return (members[:n_members], elems[:n_elems], open_start, open_member, depth, 0, ERR_NONE,
            -1, top_end)


_scan_compiled = None


def _get_scanner():  # type: ignore[no-untyped-def]
    global _scan_compiled
    if _scan_compiled is None:
        import numba

        _scan_compiled = numba.njit(cache=True, nogil=True)(_scan_py)
    return _scan_compiled


def scan_document(data: bytes | bytearray | memoryview) -> ScanResult:
    """Find top-level members and the elements of top-level arrays in a JSON object.

    Parameters
    ----------
    data : bytes-like
        The whole document (UTF-8).

    Returns
    -------
    ScanResult
        Offsets; for damaged input ``error``/``error_pos`` or ``depth > 0`` say what happened.

    Notes
    -----
    One pass over the bytes in a numba-compiled loop (about 1 GB/s); no Python objects are
    built. Only the structure is checked (brackets, strings); values are validated later by the
    parser of each element.
    """
    buf = np.frombuffer(data, dtype=np.uint8)
    cap = max(4096, buf.size // 512)
    while True:
        members, elems, open_start, open_member, depth, in_str, err, err_pos, top_end = (
            _get_scanner()(buf, _CLASSES, cap)
        )
        if err != ERR_CAPACITY:
            break
        cap *= 8
    ws = b"\xef\xbb\xbf \t\r\n"
    head = bytes(buf[:65536])
    lead = len(head) - len(head.lstrip(ws))
    if lead < len(head) and head[lead : lead + 1] != b"{":
        err, err_pos = ERR_NOT_OBJECT, lead  # number characters are skipped by the fast path
    elif err == ERR_NONE and depth == 0 and top_end >= 0:
        tail = bytes(buf[top_end + 1 :])
        if tail.strip(ws):
            err, err_pos = ERR_TRAILING, top_end + 1 + len(tail) - len(tail.lstrip(ws))
    return ScanResult(
        members=np.asarray(members),
        elements=np.asarray(elems),
        open_element_start=int(open_start),
        open_element_member=int(open_member),
        depth=int(depth),
        in_string=bool(in_str),
        error=int(err),
        error_pos=int(err_pos),
    )


def close_partial(text: bytes, *, max_attempts: int = 200) -> tuple[object, int] | None:
    """Recover the longest complete prefix of a truncated JSON value.

    Cuts ``text`` after the last complete element (at a ``,`` outside strings), closes the
    brackets still open and parses the result; tries earlier cut points until one parses.

    Parameters
    ----------
    text : bytes
        The start of a JSON value that was cut off.
    max_attempts : int, default 200
        How many cut points to try, from the end.

    Returns
    -------
    (object, int) or None
        The parsed value and the number of bytes of ``text`` it used; ``None`` if nothing
        could be recovered.
    """
    import orjson

    # positions of commas outside strings, with the stack of open brackets at that point
    cuts: list[tuple[int, str]] = []
    stack: list[str] = []
    in_str = False
    i = 0
    n = len(text)
    while i < n:
        ch = text[i]
        if in_str:
            if ch == 92:
                i += 2
                continue
            if ch == 34:
                in_str = False
        elif ch == 34:
            in_str = True
        elif ch in (123, 91):
            stack.append("}" if ch == 123 else "]")
        elif ch in (125, 93):
            if stack:
                stack.pop()
        elif ch == 44:
            cuts.append((i, "".join(reversed(stack))))
        i += 1
    for pos, closers in reversed(cuts[-max_attempts:]):
        candidate = text[:pos] + closers.encode()
        try:
            return orjson.loads(candidate), pos
        except orjson.JSONDecodeError:
            continue
    return None
