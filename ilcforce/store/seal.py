"""Checksums over what HDF5 does not checksum, or recomputes for whoever edits (the table in
docs/store-format.md says what each catches and what none of them does: a deliberate rewrite):

* ``attrs_crc32`` on every object (root, group, dataset) of a sealed store: CRC-32 over its other
  attributes, names sorted, each as its name, kind and value's bytes (:func:`attrs_checksum`),
  written after the object's last attribute change in a commit (:func:`seal_attrs`). HDF5 keeps
  no checksum of an attribute's value: a flipped bit in ``config_json`` was read as written.
* ``strings_crc32`` on every string column of a study store: CRC-32 over its values, each as its
  length (uint32 LE) and UTF-8 bytes, continued value by value (an append costs the new values).
* ``data_sha256`` on every numeric column of a study store: sha256 over its path and its values
  (:func:`data_digest`). An edit through h5py recomputes Fletcher-32 for free, not this; as it
  names the path, a column hard-linked to another's data fails it too.
"""

from __future__ import annotations

import hashlib
import struct
import zlib
from collections.abc import Iterable
from typing import Any

import numpy as np

#: The attribute that seals an object's other attributes.
ATTRS_SEAL = "attrs_crc32"
#: The attribute that seals a variable-length string column.
STRINGS_SEAL = "strings_crc32"
#: The attribute that seals a numeric column's values.
DATA_SEAL = "data_sha256"


def _value_bytes(value: Any) -> bytes:
    if isinstance(value, bytes):
        return b"b" + value
    if isinstance(value, str):
        return b"s" + value.encode("utf-8", "surrogatepass")
    if isinstance(value, (bool, np.bool_)):
        return b"?" + (b"1" if value else b"0")
    if isinstance(value, (int, np.integer)):
        return b"i" + str(int(value)).encode()
    if isinstance(value, (float, np.floating)):
        return b"f" + np.float64(value).tobytes()
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "OSU":
            parts = [_value_bytes(v.decode("utf-8", "surrogateescape") if isinstance(v, bytes) else v)
                     for v in value.ravel().tolist()]
            return b"a" + str(value.shape).encode() + b"".join(struct.pack("<I", len(p)) + p for p in parts)
        return b"n" + value.dtype.str.encode() + str(value.shape).encode() + np.ascontiguousarray(value).tobytes()
    return b"r" + repr(value).encode()


def attrs_checksum(attrs) -> int:
    """CRC-32 of an h5py ``AttributeManager``'s attributes, the seal itself left out."""
    crc = 0
    for name in sorted(attrs.keys()):
        if name == ATTRS_SEAL:
            continue
        part = name.encode("utf-8", "surrogatepass")
        value = _value_bytes(attrs[name])
        crc = zlib.crc32(struct.pack("<II", len(part), len(value)) + part + value, crc)
    return crc & 0xFFFFFFFF


def seal_attrs(obj) -> None:
    """Write ``obj``'s seal (after its last attribute change)."""
    obj.attrs[ATTRS_SEAL] = np.uint32(attrs_checksum(obj.attrs))


def attrs_state(obj) -> str:
    """``"ok"`` (sealed and intact), ``"unsealed"`` (no seal) or ``"damaged"`` (seal does not match)."""
    if ATTRS_SEAL not in obj.attrs:
        return "unsealed"
    stored = obj.attrs[ATTRS_SEAL]
    if not isinstance(stored, (np.integer, int)) or isinstance(stored, (bool, np.bool_)):
        return "damaged"
    return "ok" if int(stored) == attrs_checksum(obj.attrs) else "damaged"


def strings_checksum(values: Iterable[str], start: int = 0) -> int:
    """CRC-32 over ``values`` continued from ``start`` (the checksum of the values before them)."""
    crc = start
    for value in values:
        data = str(value).encode("utf-8", "surrogatepass")
        crc = zlib.crc32(struct.pack("<I", len(data)) + data, crc)
    return crc & 0xFFFFFFFF


def data_digest(path: str, values: np.ndarray) -> str:
    """sha256 (hex) over a numeric column's path in its file and its values (little-endian)."""
    values = np.ascontiguousarray(values, dtype=values.dtype.newbyteorder("<"))
    return hashlib.sha256(path.encode() + b"\0" + values.dtype.str.encode() + b"\0" + values.tobytes()).hexdigest()
