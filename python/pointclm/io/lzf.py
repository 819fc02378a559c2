"""LZF decompression in pure Python, for PCL's ``binary_compressed`` PCD files.

Why our own: the PyPI LZF bindings (``python-lzf``, ``python-neo-lzf``) are C extensions
with per-Python-version wheels, and pointclm's default install is numpy-only. LZF is a tiny
format (a control byte, then either a literal run or a back-reference), and the block sizes
in PCD files are a few MB at most, so a careful pure-Python loop is fast enough: copies are
done with slices, and overlapping back-references (runs of a repeated pattern, common in
NaN-filled organised clouds) are expanded by repeating the pattern rather than byte by byte.
"""

from __future__ import annotations

__all__ = ["LZF_MAX_EXPANSION", "lzf_decompress"]

#: The most output LZF makes per input byte: a 3-byte back-reference copies 264 bytes. A
#: header promising more than this many times its compressed size is lying.
LZF_MAX_EXPANSION = 88


def lzf_decompress(data: bytes | bytearray | memoryview, out_size: int) -> bytes:
    """Decompress one LZF block whose decompressed size is known in advance.

    Parameters
    ----------
    data : bytes-like
        The compressed block (no header; PCD stores the two sizes before it).
    out_size : int
        Exact size of the decompressed data.

    Returns
    -------
    bytes
        ``out_size`` bytes.

    Raises
    ------
    ValueError
        If the block is truncated or corrupt (a reference before the start of the output,
        or output longer or shorter than ``out_size``).
    """
    src = bytes(data)
    n_in = len(src)
    if out_size < 0 or out_size > LZF_MAX_EXPANSION * n_in:
        # Refused before the output buffer is allocated.
        raise ValueError(
            f"LZF block of {n_in} bytes cannot decompress to {out_size} bytes "
            f"(at most {LZF_MAX_EXPANSION}x)"
        )
    out = bytearray(out_size)
    try:
        op = _decode(src, out)
    except IndexError:
        raise ValueError("LZF data is truncated (ends inside a back-reference)") from None
    if op != out_size:
        raise ValueError(f"LZF data decompresses to {op} bytes, the header says {out_size}")
    return bytes(out)


def _decode(src: bytes, out: bytearray) -> int:
    """Decode the tokens of `src` into `out` (its length the stated size); the bytes written.

    One loop, no call per token: this is the hot path of a compressed PCD file.
    """
    n_in, out_size = len(src), len(out)
    ip = 0
    op = 0
    while ip < n_in:
        ctrl = src[ip]
        ip += 1
        if ctrl < 32:
            # Literal run of ctrl + 1 bytes.
            length = ctrl + 1
            if ip + length > n_in:
                raise ValueError("LZF data is truncated (literal run past the end)")
            if op + length > out_size:
                raise ValueError("LZF data decompresses to more than the stated size")
            out[op : op + length] = src[ip : ip + length]
            ip += length
            op += length
            continue
        # Back-reference: 3-bit length (7 = extended by the next byte), 13-bit offset.
        length = ctrl >> 5
        if length == 7:
            length += src[ip]
            ip += 1
        ref = op - ((ctrl & 0x1F) << 8) - src[ip] - 1
        ip += 1
        length += 2
        if ref < 0:
            raise ValueError("LZF data is corrupt (back-reference before the start)")
        if op + length > out_size:
            raise ValueError("LZF data decompresses to more than the stated size")
        dist = op - ref
        if dist >= length:
            out[op : op + length] = out[ref : ref + length]
        else:
            pattern = bytes(out[ref:op])
            out[op : op + length] = (pattern * (length // dist + 1))[:length]
        op += length
    return op
