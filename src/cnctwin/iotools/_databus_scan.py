"""One pass over a Databus ``bulk`` message of numbers, without a Python object per value.

:func:`scan_bulk` reads the documented layout (``{"seq": n, "vals": [{"id": "101", "qc": 3,
"ts": "2021-03-10T22:23:04.146Z", "val": 80.5}, ...]}``, keys in any order, any JSON
whitespace) in a numba-compiled loop: per value the datapoint's column (from a lookup table of
the metadata's ids), the timestamp in ns since the epoch (parsed once per distinct timestamp:
an HF message repeats one per cycle), the quality code, and the number, read into a float64
in the same pass (the Eisel-Lemire algorithm below: correctly rounded, bit for bit what every
JSON parser of the project gives, and no Python float per value); a number outside its range
(a subnormal, more than 19 significant digits) and every one after it is copied as text into
one ``[v0,v1,...]`` buffer that ``orjson`` reads. Anything outside that strict subset
(escapes, quoted or 64-bit numbers, text values, other keys, a timestamp with an offset, ids
that are not plain decimals, an irregular layout) is declined: the caller then uses the
general decoder, which handles and names every shape.

From the second row on, a value object is first compared byte for byte with the first row's
object at its place (the template: the same id, qc and keys, written the same way), so only
its timestamp (compared with its row's) and its number are read; an object written otherwise
is parsed in full. A 500-cycle HF message of 11 datapoints: 0.8 ms against 1.4 ms for a typed
``msgspec`` decode into objects (BENCHMARKS.md, "Many machines live"); with the numbers read
in the scan and without numba's reference counting ~0.45 ms (BENCHMARKS.md, "the scan without
numba's reference counting"); with the template compared 8 bytes per load ~0.3 ms
(BENCHMARKS.md, session 26).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["BulkScan", "id_table", "prepare_scanner", "scan_bulk"]

OK = 0
DECLINED = 1
MAX_ID = 1 << 20  # ids above this (or not plain decimals): no lookup table, no fast path

_K_SEQ, _K_VALS, _K_ID, _K_QC, _K_TS, _K_VAL = 1, 2, 3, 4, 5, 6


@dataclass(frozen=True)
class BulkScan:
    """What :func:`scan_bulk` read from one message (regular HF layout only).

    Attributes
    ----------
    k : int
        Values per row (datapoints per timestamp).
    cols : numpy.ndarray of int64
        Column index (into the lookup table's names) of the first row's ``k`` values.
    t_ns : numpy.ndarray of int64
        Timestamp of each row [ns since the epoch, UTC].
    values : numpy.ndarray of float64
        The values, row by row (``n_rows * k``).
    qc : numpy.ndarray of int64
        Quality code of each value.
    seq : int or None
        The message's ``seq`` (None when absent or null).
    """

    k: int
    cols: NDArray[np.int64]
    t_ns: NDArray[np.int64]
    values: NDArray[np.float64]
    qc: NDArray[np.int64]
    seq: int | None


def id_table(id_to_column: dict[str, int]) -> NDArray[np.int64] | None:
    """A lookup table id -> column index (-1: unknown) for :func:`scan_bulk`.

    None when an id is not a plain decimal below ``MAX_ID`` (``"0101"``, ``"a7"``): the
    fast path is then off for this metadata.
    """
    if not id_to_column:
        return None
    keys: list[tuple[int, int]] = []
    for k, c in id_to_column.items():
        if not (k.isascii() and k.isdigit()) or str(int(k)) != k or int(k) >= MAX_ID:
            return None
        keys.append((int(k), c))
    lut = np.full(max(i for i, _ in keys) + 1, -1, dtype=np.int64)
    for i, c in keys:
        lut[i] = c
    return lut


def _ws(buf, i, n):  # type: ignore[no-untyped-def]
    while i < n and (buf[i] == 32 or buf[i] == 9 or buf[i] == 10 or buf[i] == 13):
        i += 1
    return i


def _key(buf, i, n):  # type: ignore[no-untyped-def]
    """Key at buf[i] == '"': (code, index after the closing quote); code 0: another key."""
    if i + 6 > n:
        return 0, -1
    a = buf[i + 1]
    b = buf[i + 2]
    c = buf[i + 3]
    if c == 34:
        if a == 105 and b == 100:  # "id"
            return _K_ID, i + 4
        if a == 113 and b == 99:  # "qc"
            return _K_QC, i + 4
        if a == 116 and b == 115:  # "ts"
            return _K_TS, i + 4
        return 0, -1
    if buf[i + 4] == 34:
        if a == 118 and b == 97 and c == 108:  # "val"
            return _K_VAL, i + 5
        if a == 115 and b == 101 and c == 113:  # "seq"
            return _K_SEQ, i + 5
        return 0, -1
    if a == 118 and b == 97 and c == 108 and buf[i + 4] == 115 and buf[i + 5] == 34:
        return _K_VALS, i + 6  # "vals"
    return 0, -1


def _colon(buf, i, n):  # type: ignore[no-untyped-def]
    i = _ws(buf, i, n)
    if i >= n or buf[i] != 58:
        return -1
    return _ws(buf, i + 1, n)


def _sep(buf, i, n, close):  # type: ignore[no-untyped-def]
    """After a member or element: (1, index after ',') or (2, index after ``close``) or
    (0, -1)."""
    i = _ws(buf, i, n)
    if i < n and buf[i] == 44:
        return 1, i + 1
    if i < n and buf[i] == close:
        return 2, i + 1
    return 0, -1


def _digits(buf, i, n):  # type: ignore[no-untyped-def]
    j = i
    while j < n and 48 <= buf[j] <= 57:
        j += 1
    return j


def _int_token(buf, i, n, allow_minus):  # type: ignore[no-untyped-def]
    """A JSON integer (no leading zeros, at most 18 digits): (value, end); end -1: not one."""
    neg = False
    if allow_minus and i < n and buf[i] == 45:
        neg = True
        i += 1
    j = _digits(buf, i, n)
    if j == i or j - i > 18 or (buf[i] == 48 and j - i > 1):
        return 0, -1
    if j < n and (buf[j] == 46 or buf[j] == 101 or buf[j] == 69):
        return 0, -1  # a fraction or exponent: not an integer
    v = 0
    for p in range(i, j):
        v = v * 10 + (buf[p] - 48)
    return (-v if neg else v), j


def _num(buf, i, n, d):  # type: ignore[no-untyped-def]
    """A fixed-width number of d digits at i, or -1."""
    if i + d > n:
        return -1
    v = 0
    for p in range(i, i + d):
        c = buf[p]
        if c < 48 or c > 57:
            return -1
        v = v * 10 + (c - 48)
    return v


def _days(y, m, d):  # type: ignore[no-untyped-def]
    """Days since 1970-01-01 of a proleptic Gregorian date (H. Hinnant's days_from_civil)."""
    if m <= 2:
        y -= 1
    era = (y if y >= 0 else y - 399) // 400
    yoe = y - era * 400
    mp = m - 3 if m > 2 else m + 9
    doy = (153 * mp + 2) // 5 + d - 1
    doe = yoe * 365 + yoe // 4 - yoe // 100 + doy
    return era * 146097 + doe - 719468


def _timestamp(buf, i, j):  # type: ignore[no-untyped-def]
    """``YYYY-MM-DDThh:mm:ss[.f{1,9}][Z]`` in buf[i:j]: (True, ns since the epoch) or
    (False, 0)."""
    bad = (False, np.int64(0))
    if j - i < 19:
        return bad
    y = _num(buf, i, j, 4)
    mo = _num(buf, i + 5, j, 2)
    d = _num(buf, i + 8, j, 2)
    hh = _num(buf, i + 11, j, 2)
    mi = _num(buf, i + 14, j, 2)
    ss = _num(buf, i + 17, j, 2)
    if (buf[i + 4] != 45 or buf[i + 7] != 45 or buf[i + 10] != 84 or buf[i + 13] != 58
            or buf[i + 16] != 58):
        return bad
    if y < 1678 or y > 2261 or mo < 1 or mo > 12 or d < 1 or hh < 0 or hh > 23 or mi < 0 \
            or mi > 59 or ss < 0 or ss > 59:
        return bad
    leap = (y % 4 == 0 and y % 100 != 0) or y % 400 == 0
    dim = 31
    if mo == 2:
        dim = 29 if leap else 28
    elif mo == 4 or mo == 6 or mo == 9 or mo == 11:
        dim = 30
    if d > dim:
        return bad
    p = i + 19
    frac = 0
    if p < j and buf[p] == 46:
        q = _digits(buf, p + 1, j)
        nd = q - p - 1
        if nd < 1 or nd > 9:
            return bad
        for r in range(p + 1, q):
            frac = frac * 10 + (buf[r] - 48)
        for _ in range(9 - nd):
            frac *= 10
        p = q
    if p < j and buf[p] == 90:
        p += 1
    if p != j:
        return bad
    return True, np.int64(((_days(y, mo, d) * 24 + hh) * 60 + mi) * 60 + ss) * 1_000_000_000 \
        + frac


def _number(buf, i, n):  # type: ignore[no-untyped-def]
    """End of a JSON number at i (an integer at most 15 digits: exact in a float), or -1."""
    j = i
    if j < n and buf[j] == 45:
        j += 1
    k = _digits(buf, j, n)
    if k == j or (buf[j] == 48 and k - j > 1):
        return -1
    integer = True
    if k < n and buf[k] == 46:
        q = _digits(buf, k + 1, n)
        if q == k + 1:
            return -1
        k = q
        integer = False
    if k < n and (buf[k] == 101 or buf[k] == 69):
        q = k + 1
        if q < n and (buf[q] == 43 or buf[q] == 45):
            q += 1
        r = _digits(buf, q, n)
        if r == q:
            return -1
        k = r
        integer = False
    if integer and k - j > 15:
        return -1  # may exceed 2**53: the general path decides
    return k


# ---------------------------------------------------------------- decimal text -> float64
# The Eisel-Lemire algorithm (D. Lemire, "Number parsing at a gigabyte per second", Software:
# Practice and Experience 51(8), 2021; N. Mushtak and D. Lemire, "Fast number parsing without
# fallback", ibid. 53(7), 2023: with at most 19 significant digits the 128-bit product below
# always decides the correctly rounded double). Subnormal and overflowing results, more than
# 19 significant digits and decimal exponents outside [-342, 308] are declined (the caller
# then parses the message's numbers with orjson), so what is returned is always the correctly
# rounded double, the value every JSON parser of the project gives (tested against Python's
# ``float`` on random and boundary texts: tests/iotools/test_databus_numbers.py).

_POW5_MIN = -342
_POW5_MAX = 308


def _pow5_table() -> NDArray[np.uint64]:
    """128-bit 5**q for q in [-342, 308] (high, low words), normalized to a leading 1 bit:
    truncated for q >= 0, the reciprocal rounded up for q < 0 (as the paper's table)."""
    rows = []
    for q in range(_POW5_MIN, 0):
        p5 = 5 ** -q
        z = p5.bit_length() if p5 & (p5 - 1) else p5.bit_length() - 1  # ceil(log2(p5))
        if q >= -27:
            c = 2 ** (z + 127) // p5 + 1
        else:
            c = 2 ** (2 * z + 128) // p5 + 1
            c >>= max(c.bit_length() - 128, 0)
        rows.append(c)
    for q in range(0, _POW5_MAX + 1):
        p5 = 5 ** q
        shift = 128 - p5.bit_length()
        rows.append(p5 << shift if shift >= 0 else p5 >> -shift)
    out = np.empty(2 * len(rows), dtype=np.uint64)
    for k, c in enumerate(rows):
        out[2 * k] = c >> 64
        out[2 * k + 1] = c & 0xFFFFFFFFFFFFFFFF
    return out


_POW5 = _pow5_table()
_M32 = np.uint64(0xFFFFFFFF)
_S32 = np.uint64(32)


def _mul128(a, b):  # type: ignore[no-untyped-def]
    """The full 128-bit product of two uint64: (high, low)."""
    a_lo = a & _M32
    a_hi = a >> _S32
    b_lo = b & _M32
    b_hi = b >> _S32
    p0 = a_lo * b_lo
    p1 = a_lo * b_hi
    p2 = a_hi * b_lo
    p3 = a_hi * b_hi
    mid = (p0 >> _S32) + (p1 & _M32) + (p2 & _M32)
    lo = (p0 & _M32) | (mid << _S32)
    hi = p3 + (p1 >> _S32) + (p2 >> _S32) + (mid >> _S32)
    return hi, lo


def _sig_digits(buf, i, ve, w, nd):  # type: ignore[no-untyped-def]
    """The decimal digits from buf[i] on appended to the significand ``w`` (``nd``
    significant digits so far, leading zeros not counted): (ok, end, w, nd); not ok where a
    20th significant digit comes."""
    ten = np.uint64(10)
    while i < ve and 48 <= buf[i] <= 57:
        d = buf[i] - 48
        if nd > 0 or d != 0:
            if nd == 19:
                return False, i, w, nd
            w = w * ten + np.uint64(d)
            nd += 1
        i += 1
    return True, i, w, nd


def _float_bits(buf, vs, ve, pow5):  # type: ignore[no-untyped-def]
    """The JSON number text buf[vs:ve] (grammar checked by ``_number``) as the bits of the
    correctly rounded float64: (ok, bits); not ok where the text is declined (see above)."""
    i = vs
    neg = buf[i] == 45
    if neg:
        i += 1
    q = 0
    ok, i, w, nd = _sig_digits(buf, i, ve, np.uint64(0), 0)  # the integer part
    if not ok:
        return False, np.uint64(0)
    if i < ve and buf[i] == 46:  # the fraction: each digit one power of ten down
        ok, j, w, nd = _sig_digits(buf, i + 1, ve, w, nd)
        if not ok:
            return False, np.uint64(0)
        q -= j - (i + 1)
        i = j
    if i < ve and (buf[i] == 101 or buf[i] == 69):
        i += 1
        sign = 1
        if buf[i] == 45:
            sign = -1
            i += 1
        elif buf[i] == 43:
            i += 1
        e = 0
        while i < ve and 48 <= buf[i] <= 57:
            e = e * 10 + (buf[i] - 48)
            if e > 100000:
                return False, np.uint64(0)
            i += 1
        q += sign * e
    sign_bit = np.uint64(1) << np.uint64(63) if neg else np.uint64(0)
    if w == 0:
        return True, sign_bit  # +-0.0
    if q < _POW5_MIN or q > _POW5_MAX:
        return False, np.uint64(0)
    lz = 0  # leading zeros of w, by halving steps
    for width in (32, 16, 8, 4, 2, 1):
        if w < (np.uint64(1) << np.uint64(64 - width)):
            w = w << np.uint64(width)
            lz += width
    idx = 2 * (q - _POW5_MIN)
    hi, lo = _mul128(w, pow5[idx])
    if (hi & np.uint64(0x1FF)) == np.uint64(0x1FF):
        hi2, _ = _mul128(w, pow5[idx + 1])
        lo2 = lo + hi2
        if hi2 > lo2:
            hi = hi + np.uint64(1)
        lo = lo2
    upperbit = int(hi >> np.uint64(63))
    shift = np.uint64(upperbit + 9)
    mant = hi >> shift
    power2 = (((152170 + 65536) * q) >> 16) + 63 + upperbit - lz + 1023
    if power2 <= 0:
        return False, np.uint64(0)  # subnormal
    one = np.uint64(1)
    if lo <= one and -4 <= q <= 23 and (mant & np.uint64(3)) == one \
            and (mant << shift) == hi:
        mant = mant & ~one  # exactly halfway: round to even
    mant = mant + (mant & one)
    mant = mant >> one
    if mant >= (np.uint64(2) << np.uint64(52)):
        mant = np.uint64(1) << np.uint64(52)
        power2 += 1
    mant = mant & ~(np.uint64(1) << np.uint64(52))
    if power2 >= 0x7FF:
        return False, np.uint64(0)  # overflow
    return True, mant | (np.uint64(power2) << np.uint64(52)) | sign_bit


def _obj(buf, i, n, lut):  # type: ignore[no-untyped-def]
    """A value object at buf[i] (``{"id", "qc", "ts", "val"}`` in any order; ``qc`` may be
    left out): (ok, end, column, qc, ts start, ts end, number start, number end)."""
    bad = (False, 0, 0, 0, 0, 0, 0, 0)
    if i >= n or buf[i] != 123:
        return bad
    i += 1
    got = 0
    c = -1
    q = 3
    ts_s = -1
    ts_e = -1
    v_s = -1
    v_e = -1
    while True:
        i = _ws(buf, i, n)
        if i >= n or buf[i] != 34:
            return bad
        key, i = _key(buf, i, n)
        if key < _K_ID:
            return bad
        bit = 1 << (key - _K_ID)
        if got & bit:
            return bad
        got |= bit
        i = _colon(buf, i, n)
        if i < 0 or i >= n:
            return bad
        if key == _K_ID:
            if buf[i] != 34:
                return bad
            v, e = _int_token(buf, i + 1, n, False)
            if e < 0 or e >= n or buf[e] != 34 or v >= lut.size:
                return bad
            c = lut[v]
            if c < 0:
                return bad
            i = e + 1
        elif key == _K_QC:
            v, e = _int_token(buf, i, n, True)
            if e < 0:
                return bad
            q = v
            i = e
        elif key == _K_TS:
            if buf[i] != 34:
                return bad
            e = i + 1
            while e < n and buf[e] != 34:
                e += 1
            if e >= n:
                return bad
            ts_s = i + 1
            ts_e = e
            i = e + 1
        else:  # val
            e = _number(buf, i, n)
            if e < 0:
                return bad
            v_s = i
            v_e = e
            i = e
        more, i = _sep(buf, i, n, 125)
        if more == 0:
            return bad
        if more == 2:
            break
    if (got & 13) != 13:  # id, ts and val are required (qc defaults to 3)
        return bad
    return True, i, c, q, ts_s, ts_e, v_s, v_e


def _load8(buf, p):  # type: ignore[no-untyped-def]
    """The 8 bytes at ``p`` as one little-endian word (compiled: one unaligned load,
    :func:`_load8_intrinsic`)."""
    return int.from_bytes(bytes(buf[p:p + 8]), "little")


def _same_bytes(buf, a, b, m):  # type: ignore[no-untyped-def]
    """``buf[a:a + m] == buf[b:b + m]``, 8 bytes per compare from 8 bytes on (the last word
    overlapping the one before), byte by byte below. A value object is ~56 bytes compared
    in four pieces: 50 ns byte by byte, 12 ns in words, ~40 % of the scan of a 1 s HF
    message (BENCHMARKS.md, session 26)."""
    if m >= 8:
        x = 0
        while x + 8 <= m:
            if _load8(buf, a + x) != _load8(buf, b + x):
                return False
            x += 8
        if x < m:
            return _load8(buf, a + m - 8) == _load8(buf, b + m - 8)
        return True
    for x in range(m):  # noqa: SIM110 (numba compiles no generator in all())
        if buf[a + x] != buf[b + x]:
            return False
    return True


def _like(buf, p, n, t0, a, ln, b, vl, e, row_ts, new_row):  # type: ignore[no-untyped-def]
    """The object at p written as the template object at t0 (its timestamp at offset a,
    ``ln`` long; its number at offset b, ``vl`` long; its end at offset e), byte for byte but
    for the timestamp (the row's, or for a new row one of the same length that differs) and
    the number: (ok, end, number start, number end). The same bytes mean the same id, qc and
    keys as the template, which the full parse validated."""
    bad = (False, 0, 0, 0)
    if p + b > n or not _same_bytes(buf, p, t0, a):
        return bad
    ts = p + a
    if new_row:
        if _same_bytes(buf, ts, row_ts, ln):
            return bad
    elif not _same_bytes(buf, ts, row_ts, ln):
        return bad
    if not _same_bytes(buf, p + a + ln, t0 + a + ln, b - a - ln):
        return bad
    vs = p + b
    ve = _number(buf, vs, n)
    if ve < 0:
        return bad
    fl = e - b - vl  # what follows the number, the closing brace included
    if ve + fl > n or not _same_bytes(buf, ve, t0 + b + vl, fl):
        return bad
    return True, ve + fl, vs, ve


_TEMPLATES = 256  # row positions with a template (a row of more values parses the rest fully)


def _vals(buf, i, n, lut, tok, nt, col, t_row, qc, bits, pow5, tpl):  # type: ignore[no-untyped-def]
    """The ``vals`` array after its '[': (ok, end, values, values per row, tokens, leading
    values whose number is in ``bits``; the later numbers' texts are the tokens)."""
    bad = (False, 0, 0, 0, 0, 0)
    i = _ws(buf, i, n)
    if i < n and buf[i] == 93:
        return bad  # no values: nothing to decode fast
    tpl[:, 0] = 0  # per row place: usable, t0, a, ln, b, vl, e
    nv = 0
    k = 0
    n_rows = 0
    row_ts = -1
    prev_s = -1
    prev_e = -1
    n_exact = 0  # the leading values whose number is in bits
    while True:
        i = _ws(buf, i, n)
        j = nv % k if k > 0 else 0
        ok = False
        c = 0
        q = 0
        ts_s = 0
        ts_e = 0
        vs = 0
        ve = 0
        end = 0
        same = False
        if k > 0 and j < _TEMPLATES and tpl[j, 0] == 1:
            ok, end, vs, ve = _like(buf, i, n, tpl[j, 1], tpl[j, 2], tpl[j, 3], tpl[j, 4],
                                    tpl[j, 5], tpl[j, 6], row_ts, j == 0)
            if ok:
                c = col[j]
                q = qc[j]
                ts_s = i + tpl[j, 2]
                ts_e = ts_s + tpl[j, 3]
                same = j != 0
        if not ok:
            ok, end, c, q, ts_s, ts_e, vs, ve = _obj(buf, i, n, lut)
            if not ok:
                return bad
            same = prev_s >= 0 and ts_e - ts_s == prev_e - prev_s and \
                _same_bytes(buf, ts_s, prev_s, ts_e - ts_s)
        if nv >= qc.size or nt + (ve - vs) + 2 > tok.size:
            return bad
        # the regular layout: the first row's k ids, then the same ids in the same order for
        # each timestamp in turn
        if nv == 0:
            good, t = _timestamp(buf, ts_s, ts_e)
            if not good:
                return bad
            t_row[0] = t
            n_rows = 1
            row_ts = ts_s
        elif same:
            if k != 0 and nv % k == 0:
                return bad  # more values in this row than in the first
        else:
            if k == 0:
                k = nv
            if nv % k != 0:
                return bad  # a row ended early
            good, t = _timestamp(buf, ts_s, ts_e)
            if not good:
                return bad
            t_row[n_rows] = t
            n_rows += 1
            row_ts = ts_s
        if k != 0 and nv >= k and col[nv % k] != c:
            return bad
        if k == 0 or nv < k:
            for p in range(nv):
                if col[p] == c:
                    return bad  # a column twice in one row
            col[nv] = c
            if nv < _TEMPLATES and ts_e <= vs:  # this object is the template of its place
                tpl[nv, 0] = 1
                tpl[nv, 1] = i
                tpl[nv, 2] = ts_s - i
                tpl[nv, 3] = ts_e - ts_s
                tpl[nv, 4] = vs - i
                tpl[nv, 5] = ve - vs
                tpl[nv, 6] = end - i
        qc[nv] = q
        parsed = False
        if n_exact == nv:  # every number before this one read into bits
            parsed, b = _float_bits(buf, vs, ve, pow5)
            if parsed:
                bits[nv] = b
                n_exact += 1
        if not parsed:  # from the first declined number on, the texts for orjson
            for p in range(vs, ve):
                tok[nt] = buf[p]
                nt += 1
            tok[nt] = 44  # ,
            nt += 1
        nv += 1
        prev_s = ts_s
        prev_e = ts_e
        more, i = _sep(buf, end, n, 93)
        if more == 0:
            return bad
        if more == 2:
            break
    if k == 0:
        k = nv
    if nv % k != 0:
        return bad
    return True, i, nv, k, nt, n_exact


def _scan_py(buf, lut, tok, col, t_row, qc, bits, pow5, tpl):  # type: ignore[no-untyped-def]
    """Returns (status, n_values, k, n_tok, has_seq, seq, n_exact: values read into bits)."""
    n = buf.size
    i = _ws(buf, 0, n)
    if i >= n or buf[i] != 123:
        return DECLINED, 0, 0, 0, 0, 0, 0
    i += 1
    has_seq = 0
    seq = 0
    seen_vals = False
    n_exact = 0
    nv = 0
    nt = 0
    k = 0
    tok[nt] = 91  # [
    nt += 1
    first = True
    while True:
        i = _ws(buf, i, n)
        if i >= n:
            return DECLINED, 0, 0, 0, 0, 0, 0
        if buf[i] == 125 and first:
            i += 1
            break
        if buf[i] != 34:
            return DECLINED, 0, 0, 0, 0, 0, 0
        key, i = _key(buf, i, n)
        if key == 0:
            return DECLINED, 0, 0, 0, 0, 0, 0
        i = _colon(buf, i, n)
        if i < 0 or i >= n:
            return DECLINED, 0, 0, 0, 0, 0, 0
        if key == _K_SEQ:
            if has_seq != 0:
                return DECLINED, 0, 0, 0, 0, 0, 0
            if buf[i] == 34:  # "123": the decoder reads a digit string as the number
                v, e = _int_token(buf, i + 1, n, False)
                if e < 0 or e >= n or buf[e] != 34:
                    return DECLINED, 0, 0, 0, 0, 0, 0
                i = e + 1
                has_seq, seq = 1, v
            elif i + 4 <= n and buf[i] == 110 and buf[i + 1] == 117 and buf[i + 2] == 108 \
                    and buf[i + 3] == 108:
                i += 4
                has_seq = 2  # null
            else:
                v, e = _int_token(buf, i, n, False)
                if e < 0:
                    return DECLINED, 0, 0, 0, 0, 0, 0
                i = e
                has_seq, seq = 1, v
        elif key == _K_VALS:
            if seen_vals or buf[i] != 91:
                return DECLINED, 0, 0, 0, 0, 0, 0
            seen_vals = True
            ok, i, nv, k, nt, n_exact = _vals(buf, i + 1, n, lut, tok, nt, col, t_row, qc,
                                              bits, pow5, tpl)
            if not ok:
                return DECLINED, 0, 0, 0, 0, 0, 0
        else:
            return DECLINED, 0, 0, 0, 0, 0, 0
        first = False
        more, i = _sep(buf, i, n, 125)
        if more == 0:
            return DECLINED, 0, 0, 0, 0, 0, 0
        if more == 2:
            break
    i = _ws(buf, i, n)
    if i != n or not seen_vals:
        return DECLINED, 0, 0, 0, 0, 0, 0
    if nt > 1:
        tok[nt - 1] = 93  # the last comma becomes ]
    return OK, nv, k, nt, has_seq, seq, n_exact


_compiled: Any = None
_compile_lock = threading.Lock()
_HELPERS = ("_ws", "_key", "_colon", "_sep", "_digits", "_int_token", "_num", "_days",
            "_timestamp", "_number", "_same_bytes", "_like", "_obj", "_mul128", "_sig_digits",
            "_float_bits", "_vals")
_PY = {name: globals()[name] for name in (*_HELPERS, "_scan_py")}  # before any compiling
_CACHE = True  # numba's on-disk cache of the compiled scan
_NO_REFCOUNT: dict[str, Any] = {"_nrt": False}
"""Without the runtime's reference counting (``_nrt``, a CPU target option of numba): the
scan allocates nothing (its arrays come from the caller, who holds them), and the atomic
increments and decrements of the arrays handed to its helpers took half of its time (perf:
two ``lock`` instructions, 51 % of the samples; BENCHMARKS.md). A numba without the option
gets the scan with reference counting."""


def _load8_intrinsic() -> Any:
    """:func:`_load8` for numba: an unaligned 8-byte load from a uint8 array (the caller
    keeps ``p + 8`` inside the array, as for the bytes it would compare one by one)."""
    from llvmlite import ir
    from numba import types
    from numba.extending import intrinsic

    @intrinsic
    def load8(typingctx, arr, idx):  # type: ignore[no-untyped-def]
        if not (isinstance(arr, types.Array) and arr.dtype == types.uint8):
            return None
        sig = types.uint64(arr, types.intp)

        def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
            ary = context.make_array(signature.args[0])(context, builder, args[0])
            ptr = builder.gep(ary.data, [args[1]])
            return builder.load(builder.bitcast(ptr, ir.IntType(64).as_pointer()), align=1)

        return sig, codegen

    return load8


def _build(options: dict[str, Any]) -> Any:
    import numba

    opts: dict[str, Any] = {"cache": _CACHE, "nogil": True, **options}
    g = globals()
    g["_load8"] = _load8_intrinsic()
    for name in _HELPERS:  # the helpers inlined where the scan calls them
        g[name] = numba.njit(**opts, inline="never" if name == "_vals" else "always")(
            _PY[name])
    return numba.njit(**opts)(_PY["_scan_py"])


_WARM_MESSAGE = (b'{"seq":1,"vals":[{"id":"1","qc":3,"ts":"2026-01-01T00:00:00.002Z",'
                 b'"val":1.5}]}')


def _scan_arrays(size: int) -> tuple[NDArray[Any], ...]:
    """The scan's output and work arrays for a message of ``size`` bytes: tokens, columns,
    row times, quality codes, number bits, row templates."""
    cap = size // 16 + 1  # a value object is at least 30 bytes
    return (np.empty(size + 2, dtype=np.uint8), np.empty(cap, dtype=np.int64),
            np.empty(cap, dtype=np.int64), np.empty(cap, dtype=np.int64),
            np.empty(cap, dtype=np.uint64), np.empty((_TEMPLATES, 7), dtype=np.int64))


def _call(fn: Any, buf: NDArray[np.uint8], lut: NDArray[np.int64],
          arrays: tuple[NDArray[Any], ...]) -> Any:
    """``fn`` (the compiled scan) on ``buf`` with the arrays of :func:`_scan_arrays`."""
    tok, col, t_row, qc, bits, tpl = arrays
    return fn(buf, lut, tok, col, t_row, qc, bits, _POW5, tpl)


def _warm(fn: Any) -> None:
    """Compile (or load from numba's cache) by scanning a one-value message."""
    buf = np.frombuffer(_WARM_MESSAGE, dtype=np.uint8)
    _call(fn, buf, np.zeros(2, dtype=np.int64), _scan_arrays(buf.size))


def _scanner() -> Any:
    global _compiled
    with _compile_lock:  # the machines of a plant worker start at once: compile once
        if _compiled is None:
            try:
                fn = _build(_NO_REFCOUNT)
                _warm(fn)
            except KeyError:  # "Unrecognized options": this numba has no such option
                fn = _build({})
                _warm(fn)
            _compiled = fn
    return _compiled


def prepare_scanner() -> None:
    """Compile (or load from numba's cache) and run the scanner once, so the first message
    of a live source does not wait for it (~0.4 s)."""
    scan_bulk(_WARM_MESSAGE, np.zeros(2, dtype=np.int64))


def scan_bulk(message: bytes, lut: NDArray[np.int64]) -> BulkScan | None:
    """Read a ``bulk`` message of numbers in the regular HF layout, or decline (None).

    Parameters
    ----------
    message : bytes
        The MQTT payload.
    lut : numpy.ndarray of int64
        :func:`id_table` of the current metadata.

    Returns
    -------
    BulkScan or None
        None for anything outside the strict subset (see the module docstring); the caller's
        general path then decodes or names it.
    """
    import orjson

    buf = np.frombuffer(message, dtype=np.uint8)
    arrays = _scan_arrays(buf.size)
    tok, col, t_row, qc, bits, _ = arrays
    status, nv, k, nt, has_seq, seq, n_exact = _call(_scanner(), buf, lut, arrays)
    if status != OK:
        return None
    # the numbers the scan read (Eisel-Lemire: no Python float per value), then those it
    # declined and all after them (orjson: subnormals, > 19 digits)
    values = bits[:nv].view(np.float64)
    if n_exact < nv:
        try:
            rest = np.array(orjson.loads(tok[:nt].tobytes()), dtype=np.float64)
        except (orjson.JSONDecodeError, OverflowError):  # 1e400: the general path says so
            return None
        if rest.size != nv - n_exact:
            return None
        values[n_exact:] = rest
    # views: the arrays were made for this call alone (no copy per message)
    return BulkScan(k=int(k), cols=col[:k], t_ns=t_row[:nv // k], values=values, qc=qc[:nv],
                    seq=int(seq) if has_seq == 1 else None)
