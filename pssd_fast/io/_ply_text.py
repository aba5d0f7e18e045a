"""ASCII PLY bodies, a whole column at a time, both ways.

Reading splits the body into tokens and parses them as ``int`` and ``float`` parse them (what
``plyfile`` does), returning None where a token or row needs ``plyfile``'s own reader. Writing
spells each float in the fewest digits that read back to the same value.
"""
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ._ply_binary import list_column, lists, ragged

# Tokens parsed at once: bounds the working memory.
PLY_TOKEN_BLOCK = 2**18
# The longest ASCII token parsed here (``%.18g`` of a double is at most 25 characters).
_TOKEN_WIDTH = 32
# Exact powers of ten in float64; a decimal of at most 15 digits times or over one of them is
# the correctly rounded value of the decimal, as Python's float() gives it.
_POW10 = 10.0 ** np.arange(23)
_INT_POW10 = 10 ** np.arange(19, dtype=np.int64)


def _byte_set(chars):
    table = np.zeros(256, np.bool_)
    table[list(chars.encode())] = True
    return table


# What separates ASCII tokens, and every byte an ASCII body may hold for the numpy reader:
# digits, signs, points, exponents and the letters of nan and inf(inity).
_BLANK = _byte_set(" \t\r\n")
_NUMERIC = _byte_set(" \t\r\n0123456789+-.eEnNaAiIfFtTyY")


# ---------------------------------------------------------------------------------------------
# Reading


@dataclass(frozen=True)
class Tokens:
    """The whitespace-separated tokens of the lines of an ASCII body."""

    text: np.ndarray  # the lines' bytes, zero-padded by _TOKEN_WIDTH for fixed-width windows
    starts: np.ndarray  # offset of each token
    stops: np.ndarray  # offset after each token
    first: np.ndarray  # index of each line's first token, and the token count after the last

    @classmethod
    def split(cls, body, lines):
        """The tokens of the first ``lines`` lines of ``body`` (a uint8 array); None where it
        has fewer lines, a token longer than :data:`_TOKEN_WIDTH` or a byte outside plain
        numbers and their separators (plyfile's reader then decides)."""
        lf, cr = body == 10, body == 13
        # Line ends as plyfile's text stream reads them: LF, CR LF and a lone CR.
        breaks = lf.copy()
        breaks[:-1] |= cr[:-1] & ~lf[1:]
        breaks[-1:] |= cr[-1:]
        ends = np.flatnonzero(breaks)
        if len(ends) >= lines:
            stop = ends[lines - 1] + 1 if lines else 0
        elif len(ends) == lines - 1 and len(body) > (ends[-1] + 1 if len(ends) else 0):
            stop = len(body)  # the last line lacks its line end
        else:
            return None
        text = body[:stop]
        if not _NUMERIC[text].all():
            return None
        inside = (~_BLANK[text]).view(np.int8)
        edges = np.diff(inside, prepend=np.int8(0), append=np.int8(0))
        starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        if len(starts) and (stops - starts).max() > _TOKEN_WIDTH:
            return None
        # The tokens before each line end: the index of the next line's first token.
        first = np.concatenate([[0], np.searchsorted(starts, ends[:lines]), [len(starts)]])
        first = first[:lines + 1]
        padded = np.concatenate([text, np.zeros(_TOKEN_WIDTH, np.uint8)])
        return cls(padded, starts, stops, first)

    def parse(self, index, dtype):
        """The tokens ``index`` as numbers of ``dtype``, as plyfile reads them; None where one
        is no plain number or does not fit ``dtype``."""
        dtype = np.dtype(dtype)
        out = np.empty(len(index), dtype)
        for at in range(0, len(index), PLY_TOKEN_BLOCK):
            part = index[at:at + PLY_TOKEN_BLOCK]
            starts, lengths = self.starts[part], self.stops[part] - self.starts[part]
            chars = sliding_window_view(self.text, int(lengths.max()))[starts]
            values = (_parse_ints(chars, lengths, dtype) if dtype.kind in "iu"
                      else _parse_floats(chars, lengths))
            if values is None:
                return None
            out[at:at + len(part)] = values
        return out


def ascii_element(element, tokens, line, plyfile):
    """The rows of ``element``, from line ``line`` of the body on; None where a row does not
    hold exactly what the header says (plyfile's reader then names the error)."""
    count = element.count
    cur = tokens.first[line:line + count].copy()
    stop = tokens.first[line + 1:line + count + 1]
    data = np.empty(count, element.dtype())
    for prop in element.properties:
        if (cur >= stop).any():
            return None
        if isinstance(prop, plyfile.PlyListProperty):
            if np.dtype(prop.len_dtype).kind not in "iu":
                return None
            lengths = tokens.parse(cur, prop.len_dtype)
            if lengths is None or (lengths < 0).any():
                return None
            lengths = lengths.astype(np.int64)
            cur = cur + 1
            if (cur + lengths > stop).any():
                return None
            values = tokens.parse(ragged(cur, lengths), prop.val_dtype)
            if values is None:
                return None
            data[prop.name] = lists(values, lengths)
            cur = cur + lengths
        else:
            values = tokens.parse(cur, prop.val_dtype)
            if values is None:
                return None
            data[prop.name] = values
            cur = cur + 1
    return data if (cur == stop).all() else None


def _parse_ints(chars, lengths, dtype):
    """Integers of ``[+-]digits`` tokens (``chars``: their bytes, one row each, and what
    follows them), as ``int(token)``; None where one is something else or does not fit."""
    cols = np.arange(chars.shape[1])
    signed = (chars[:, 0] == ord("-")) | (chars[:, 0] == ord("+"))
    inside = (cols >= signed[:, None]) & (cols < lengths[:, None])
    digits = chars - np.uint8(ord("0"))  # wraps around below "0"
    ndigits = lengths - signed
    if not ((digits < 10) | ~inside).all() or (ndigits < 1).any() or (ndigits > 18).any():
        return None
    values = np.zeros(len(chars), np.int64)
    for j in cols:
        values = np.where(inside[:, j], values * 10 + digits[:, j], values)
    values = np.where(chars[:, 0] == ord("-"), -values, values)
    info = np.iinfo(dtype)
    if len(values) and (values.min() < info.min or values.max() > info.max):
        return None
    return values


def _parse_floats(chars, lengths):
    """Float64 values of decimal tokens, as ``float(token)``; None where one is not a number.

    Tokens of at most 15 significant digits and a power of ten within 1e±22 are computed as
    one correctly rounded product or quotient (what ``float`` gives); the others (more
    digits, nan, inf) go through ``float`` itself.
    """
    cols = np.arange(chars.shape[1])
    inside = cols < lengths[:, None]
    digit = ((chars - np.uint8(ord("0"))) < 10) & inside
    expo = ((chars == ord("e")) | (chars == ord("E"))) & inside
    point = (chars == ord(".")) & inside
    sign = ((chars == ord("+")) | (chars == ord("-"))) & inside
    plain = (digit | expo | point | sign | ~inside).all(axis=1)
    n_expo, n_point = expo.sum(axis=1), point.sum(axis=1)
    at_e = np.where(n_expo > 0, expo.argmax(axis=1), lengths)
    at_point = np.where(n_point > 0, point.argmax(axis=1), at_e)
    # Signs only first and right after the exponent's "e".
    sign_ok = ~sign | (cols == 0) | ((cols == at_e[:, None] + 1) & (n_expo > 0)[:, None])
    mantissa = digit & (cols < at_e[:, None])
    exponent = digit & (cols > at_e[:, None])
    n_mantissa, n_exponent = mantissa.sum(axis=1), exponent.sum(axis=1)
    valid = (plain & (n_expo <= 1) & (n_point <= 1) & (at_point <= at_e) & sign_ok.all(axis=1)
             & (n_mantissa >= 1) & ((n_expo == 0) | (n_exponent >= 1)))
    if not (valid | ~plain).all():
        return None  # float() refuses it: plyfile's reader names the error
    value = chars - np.uint8(ord("0"))
    m = np.zeros(len(chars), np.int64)
    e = np.zeros(len(chars), np.int64)
    for j in cols:
        m = np.where(mantissa[:, j], m * 10 + value[:, j], m)
        e = np.where(exponent[:, j], e * 10 + value[:, j], e)
    rows = np.arange(len(chars))
    after_e = chars[rows, np.minimum(at_e + 1, chars.shape[1] - 1)]
    e = np.where((n_expo > 0) & (after_e == ord("-")), -e, e)
    shift = e - (mantissa & (cols > at_point[:, None])).sum(axis=1)
    exact = valid & (n_mantissa <= 15) & (n_exponent <= 4) & (np.abs(shift) <= 22)
    power = _POW10[np.clip(np.abs(shift), 0, 22)]
    mf = m.astype(np.float64)
    out = np.where(shift >= 0, mf * power, mf / power)
    out = np.where(chars[:, 0] == ord("-"), -out, out)
    rest = np.flatnonzero(~exact)
    if len(rest):
        raw = np.where(inside[rest], chars[rest], 0).view(f"S{chars.shape[1]}")[:, 0]
        try:
            out[rest] = raw.astype(np.float64)
        except ValueError:
            return None
    return out


# ---------------------------------------------------------------------------------------------
# Writing


def text_rows(element, rows, plyfile):
    """The ASCII lines of ``rows``: values separated by a space, lists as their length then
    their values."""
    if not element.properties:
        return b"\n" * len(rows)
    columns, counts = [], np.zeros(len(rows), np.int64)
    for prop in element.properties:
        if isinstance(prop, plyfile.PlyListProperty):
            lengths, values = list_column(prop, rows[prop.name], "=")
            columns.append((_tokens(lengths), lengths, _tokens(values)))
            counts += 1 + lengths
        else:
            columns.append((_tokens(rows[prop.name].astype("=" + prop.val_dtype)), None, None))
            counts += 1
    ends = np.cumsum(counts)
    cur = ends - counts
    width = max(tokens[0].shape[1] for head, _, values in columns
                for tokens in (head, values) if tokens is not None)
    # A row of bytes per token, its separator last: what is kept of them, in order, is the
    # text.
    chars = np.zeros((ends[-1], width + 1), np.uint8)
    keep = np.zeros((ends[-1], width + 1), np.bool_)
    for head, lengths, values in columns:
        chars[cur, :head[0].shape[1]], keep[cur, :head[0].shape[1]] = head
        cur = cur + 1
        if lengths is not None:
            at = ragged(cur, lengths)
            chars[at, :values[0].shape[1]], keep[at, :values[0].shape[1]] = values
            cur = cur + lengths
    chars[:, width] = ord(" ")
    chars[ends - 1, width] = ord("\n")
    keep[:, width] = True
    return chars[keep].tobytes()


def _tokens(values):
    """(chars, keep): the decimal text of each value, a row of bytes of which those ``keep``
    marks are written. Integers as they are; floats in the fewest digits that read back to
    the same value (through float64, as plyfile and ``float`` read them), spelt as Python's
    ``repr`` spells them but without a trailing ``.0``."""
    if values.dtype.kind in "iu":
        values = values.astype(np.int64)
        return _decimals(values < 0, np.abs(values), np.zeros(len(values), np.int64))
    if values.dtype.itemsize == 4:
        return _float32_tokens(values)
    return _repr_tokens([repr(v) for v in values.tolist()])


def _float32_tokens(values):
    """:func:`_tokens` of float32 values."""
    x = values.astype(np.float32)
    magnitude = np.abs(x).astype(np.float64)
    # The magnitudes repr writes without exponent; the others (and nan, inf, 0) are few.
    plain = np.flatnonzero((magnitude >= 1e-4) & (magnitude < 1e16))
    m, shift = _shortest32(magnitude[plain])
    exponent = shift + np.searchsorted(_INT_POW10[1:], m, side="right")  # of the first digit
    positional = (m > 0) & (exponent >= -4) & (exponent < 16)
    rows = plain[positional]
    chars, keep = _decimals(x[rows] < 0, m[positional], shift[positional])
    rest = np.setdiff1d(np.arange(len(x)), rows, assume_unique=True)
    # numpy writes the shortest float32 digits (Dragon4); repr of their float64 respells them.
    other_chars, other_keep = _repr_tokens([repr(float(s)) for s in x[rest].astype(str)])
    width = max(chars.shape[1], other_chars.shape[1])
    out, out_keep = np.zeros((len(x), width), np.uint8), np.zeros((len(x), width), np.bool_)
    out[rows, :chars.shape[1]], out_keep[rows, :chars.shape[1]] = chars, keep
    out[rest, :other_chars.shape[1]], out_keep[rest, :other_chars.shape[1]] = (other_chars,
                                                                               other_keep)
    return out, out_keep


def _shortest32(magnitude):
    """(m, shift) with ``float32(m * 10**shift) == magnitude`` (``m * 10**shift`` rounded to
    float64 as ``float`` reads it) for the fewest digits of ``m``, at most 9; m 0 where none
    was found. ``magnitude``: float32 values as float64, from 1e-4 to 1e16."""
    target = magnitude.astype(np.float32)
    exponent = np.floor(np.log10(magnitude)).astype(np.int64)
    exponent -= magnitude < 10.0 ** exponent  # log10 may be off by one near a power of ten
    exponent += magnitude >= 10.0 ** (exponent + 1)
    m = np.zeros(len(magnitude), np.int64)
    shift = np.zeros(len(magnitude), np.int64)

    def fits(rows, digits):
        """Which of ``rows`` have a decimal of ``digits`` digits; it is kept for those."""
        at = exponent[rows] - digits + 1
        power = _POW10[np.abs(at)]  # |at| <= 12 + 8: exact
        value = magnitude[rows]
        candidate = np.rint(np.where(at <= 0, value * power, value / power))
        back = np.where(at >= 0, candidate * power, candidate / power)
        hit = back.astype(np.float32) == target[rows]
        m[rows[hit]], shift[rows[hit]] = candidate[hit], at[hit]
        return hit

    # 9 digits always do (checked all the same), and a value that fits in some digits fits in
    # more: bisect.
    everything = np.arange(len(magnitude))
    fits(everything, np.full(len(magnitude), 9))
    low, high = np.ones(len(magnitude), np.int64), np.full(len(magnitude), 9)
    while (todo := np.flatnonzero(low < high)).size:
        mid = (low[todo] + high[todo]) // 2
        hit = fits(todo, mid)
        high[todo[hit]] = mid[hit]
        low[todo[~hit]] = mid[~hit] + 1
    # Fewest digits: a candidate may end in zeros when it rounded up to a power of ten.
    for _ in range(9):
        zero = (m % 10 == 0) & (m > 0)
        m[zero] //= 10
        shift[zero] += 1
    return m, shift


def _decimals(negative, m, shift):
    """(chars, keep) of ``±m * 10**shift`` (m >= 0) without exponent: ``12300``, ``1.23``,
    ``0.0123``, ``-7``.

    The row is a sign, the integer part's digits, a point and the fraction's digits, in
    columns the same for every row: leading zeros of the integer part, the sign of a positive
    value and the point of an integer are left out by ``keep``.
    """
    fraction = np.maximum(-shift, 0)  # digits after the point
    scale = _INT_POW10[fraction]
    whole = np.where(shift >= 0, m * _INT_POW10[np.maximum(shift, 0)], m // scale)
    wide = int(fraction.max(initial=0))
    # The fraction's digits, followed by zeros up to ``wide`` digits.
    rest = (m - whole * scale) * _INT_POW10[wide - fraction]
    digits = len(str(int(whole.max(initial=0))))
    chars = np.empty((len(m), digits + 2 + wide), np.uint8)
    keep = np.empty(chars.shape, np.bool_)
    chars[:, 0], keep[:, 0] = ord("-"), negative
    for col in range(digits, 0, -1):
        chars[:, col] = ord("0") + whole % 10
        keep[:, col] = whole > 0
        whole = whole // 10
    keep[:, digits] = True  # 0 is written "0"
    chars[:, digits + 1], keep[:, digits + 1] = ord("."), fraction > 0
    for col in range(wide, 0, -1):
        chars[:, digits + 1 + col] = ord("0") + rest % 10
        keep[:, digits + 1 + col] = fraction >= col
        rest = rest // 10
    return chars, keep


def _repr_tokens(texts):
    """(chars, keep) of Python float reprs, without a trailing ``.0``."""
    if not texts:
        return np.zeros((0, 1), np.uint8), np.zeros((0, 1), np.bool_)
    chars = np.array(texts, dtype="S").view(np.uint8).reshape(len(texts), -1)
    keep = chars != 0
    lengths = keep.sum(axis=1)
    rows = np.flatnonzero((lengths >= 2) & (chars[np.arange(len(texts)), lengths - 1] == ord("0"))
                          & (chars[np.arange(len(texts)), np.maximum(lengths - 2, 0)] == ord(".")))
    keep[rows, lengths[rows] - 1] = keep[rows, lengths[rows] - 2] = False
    return chars, keep
