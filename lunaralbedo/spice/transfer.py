"""SPICE DAF transfer files (``.xsp``, ``.xc``, ``.xfr``) to binary kernels spiceypy can load.

NAIF's ``tobin`` utility turns the portable text ("transfer") form of an SPK or CK into the
binary DAF that ``furnsh`` needs; spiceypy does not wrap the DAF writers, so this module
does the same with ``struct``.  The formats are those of the NAIF "DAF Required Reading"
and the "Converting and Porting SPICE Data Files" guide:

* transfer file: ``DAFETF NAIF DAF ENCODED TRANSFER FILE``, then the quoted file type
  (``'DAF/SPK '``), ND, NI and the internal file name; per array ``BEGIN_ARRAY i n``, its
  quoted name, ND encoded doubles and NI-2 encoded integers of its summary, the data in
  blocks (an unquoted count, then that many encoded doubles), ``END_ARRAY i n``; then
  ``TOTAL_ARRAYS``.  A number is ``[-]MANTISSA^EXPONENT`` in hexadecimal: the value is
  ``0.MANTISSA (base 16) * 16**EXPONENT``; integers are plain (signed) hexadecimal.
* binary DAF (little-endian IEEE, ``LTL-IEEE``): 1024-byte records; record 1 the file
  record (id word, ND, NI, internal name, first/last summary record, first free address,
  binary format, the FTP validation string); then pairs of summary and name records
  (summary record: next, previous, count, then the summaries of ND doubles and NI
  integers packed two to a double, the last two integers being the array's first and last
  double-word address); then the arrays' doubles.

The comment area of the transfer file is not carried over.
"""
from __future__ import annotations

import struct
from pathlib import Path

from ..errors import SpiceError
from ..io.atomic import atomic_path

MAGIC = "DAFETF NAIF DAF ENCODED TRANSFER FILE"
RECORD = 1024
_FTP = b"FTPSTR:\r:\n:\r\n:\r\x00:\x81:\x10\xce:ENDFTP"


def is_transfer_file(path: str | Path) -> bool:
    """True when ``path`` starts with the DAF transfer-file magic line."""
    try:
        with open(path, "rb") as f:
            return f.read(len(MAGIC)).decode("latin-1") == MAGIC
    except OSError:
        return False


def decode_double(text: str) -> float:
    """A transfer-format number ``[-]MANTISSA^EXP`` (hexadecimal): ``0.MANTISSA * 16**EXP``."""
    mant, _, exp = text.partition("^")
    sign = -1.0 if mant.startswith("-") else 1.0
    digits = mant.lstrip("-")
    if digits in ("", "0"):
        return 0.0
    return sign * int(digits, 16) * 16.0 ** (int(exp or "0", 16) - len(digits))


def _unquote(line: str) -> str:
    s = line.strip()
    return s[1:-1] if len(s) >= 2 and s[0] == "'" and s[-1] == "'" else s


def parse_transfer(path: str | Path):
    """``(idword, nd, ni, ifname, arrays)``; ``arrays`` = list of ``(name, doubles, ints, data)``."""
    path = Path(path)
    with open(path, "r", encoding="latin-1") as f:
        lines = [ln.rstrip("\r\n") for ln in f]
    if not lines or lines[0].strip() != MAGIC:
        raise SpiceError(f"{path}: not a SPICE DAF transfer file (first line is not {MAGIC!r})")
    try:
        idword = _unquote(lines[1])
        nd, ni = int(_unquote(lines[2]), 16), int(_unquote(lines[3]), 16)
        ifname = _unquote(lines[4])
        arrays, i = [], 5
        while i < len(lines) and lines[i].startswith("BEGIN_ARRAY"):
            name = _unquote(lines[i + 1])
            dc = [decode_double(_unquote(v)) for v in lines[i + 2:i + 2 + nd]]
            ic = [int(_unquote(v), 16) for v in lines[i + 2 + nd:i + nd + ni]]
            i += nd + ni
            data: list[float] = []
            while not lines[i].startswith("END_ARRAY"):
                n = int(lines[i].strip())
                data.extend(decode_double(_unquote(v)) for v in lines[i + 1:i + 1 + n])
                i += n + 1
            arrays.append((name, dc, ic, data))
            i += 1
    except (IndexError, ValueError) as exc:
        raise SpiceError(f"{path}: malformed DAF transfer file near line {i + 1} ({exc})") from None
    if not idword.startswith("DAF/"):
        raise SpiceError(f"{path}: transfer file of {idword!r}, not a DAF (SPK/CK/PCK)")
    return idword, nd, ni, ifname, arrays


def write_daf(path: str | Path, idword: str, nd: int, ni: int, ifname: str, arrays) -> None:
    """A little-endian binary DAF holding ``arrays`` (see :func:`parse_transfer`), written atomically."""
    ss = nd + (ni + 1) // 2  # summary size in doubles
    nc = 8 * ss  # name length in characters
    per = (125 // ss)
    groups = [arrays[k:k + per] for k in range(0, len(arrays), per)] or [[]]
    first_data_rec = 2 + 2 * len(groups)
    addr = (first_data_rec - 1) * 128 + 1
    summaries, data_blob = [], bytearray()
    for name, dc, ic, data in arrays:
        begin, end = addr, addr + len(data) - 1
        ints = list(ic) + [begin, end]
        ints += [0] * ((ni + 1) // 2 * 2 - len(ints))
        summaries.append((struct.pack(f"<{nd}d{len(ints)}i", *dc, *ints), name.ljust(nc)[:nc].encode("latin-1")))
        data_blob += struct.pack(f"<{len(data)}d", *data)
        addr = end + 1
    free = addr
    out = bytearray()
    out += idword.ljust(8)[:8].encode("latin-1") + struct.pack("<ii", nd, ni)
    out += ifname.ljust(60)[:60].encode("latin-1")
    out += struct.pack("<iii", 2, 2 + 2 * (len(groups) - 1), free) + b"LTL-IEEE"
    out += b"\0" * 603 + _FTP + b"\0" * 297
    k = 0
    for g, group in enumerate(groups):
        nxt = 2 + 2 * (g + 1) if g + 1 < len(groups) else 0
        prv = 2 + 2 * (g - 1) if g > 0 else 0
        rec = struct.pack("<3d", nxt, prv, len(group)) + b"".join(s for s, _n in summaries[k:k + len(group)])
        names = b"".join(n for _s, n in summaries[k:k + len(group)])
        out += rec.ljust(RECORD, b"\0") + names.ljust(RECORD, b" ")
        k += len(group)
    out += data_blob
    out += b"\0" * (-len(out) % RECORD)
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(bytes(out))


def transfer_to_binary(src: str | Path, dst: str | Path) -> Path:
    """Convert the transfer file ``src`` into the binary DAF ``dst`` (what NAIF's ``tobin`` does)."""
    write_daf(dst, *parse_transfer(src))
    return Path(dst)
