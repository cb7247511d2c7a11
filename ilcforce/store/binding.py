"""What binds a stored record to its store and its place, so that a record copied from another store
(or moved within one) no longer verifies: the checksums of :mod:`.seal` only say that bytes are as
written, and HDF5 copies a group with its attributes, its checksums included.

* A run store (schema 2.2 on) has a random ``store_id``, made with the store. Its **key** is sha256 of
  that id, the run's seed, experiment, method and the digest of its configuration (the part its
  results depend on, :func:`ilcforce.samerun.relevant`: the same on every resume). Every complete
  iteration group carries ``binding_sha256``: sha256 of the key, the iteration number, the group's
  attributes (status, divergence, fallback count) and, per dataset, its name, shape and CRC-32 (the
  CRC-32s already cover every byte of the logs and memory: nothing is read twice). ``/reference``
  carries the same over the key and the reference and control-grid data. The root's
  ``n_iterations_stored`` (sealed with the root's attributes) says how many iterations the store
  holds: 0 .. n - 1, none removed.
* A study store (schema 1.3 on): its key is sha256 of its ``study_id``, simulation fingerprint and
  definition; every column carries ``binding_sha256``: sha256 of the key, the column's path and its
  seal (``data_sha256`` or ``strings_crc32``, which cover its values: :func:`column_binding`).

None of this is a signature: whoever reads this module can recompute a binding for a record they
copy. It turns a splice with plain h5py (copying groups, datasets or attributes, recomputing the
documented checksums) into a refusal; it does not stop a forger who recomputes the binding too
(docs/store-format.md, "What protects each byte").
"""

from __future__ import annotations

import hashlib
import json
import struct
import uuid
from collections.abc import Iterable

import numpy as np

#: The attribute of an iteration group and of /reference that binds it to its store and place.
BINDING = "binding_sha256"
#: The run store's random identity (root attribute, 32 hex digits).
STORE_ID = "store_id"
#: Root attribute: how many iterations the store holds (0 .. n - 1), set by every commit that adds one.
STORED = "n_iterations_stored"


def new_store_id() -> str:
    return uuid.uuid4().hex


def _field(data: bytes) -> bytes:
    return struct.pack("<Q", len(data)) + data


def config_digest(config_json: str, method: str) -> str:
    """sha256 of the part of a run's configuration its results depend on (:func:`ilcforce.samerun.relevant`,
    canonical JSON); of the text itself when it is not a JSON object."""
    from ilcforce import samerun

    try:
        config = json.loads(config_json)
    except (ValueError, RecursionError):
        config = None
    if isinstance(config, dict):
        text = json.dumps(samerun.relevant(config, method), sort_keys=True, separators=(",", ":"))
    else:
        text = str(config_json)
    return hashlib.sha256(text.encode("utf-8", "surrogatepass")).hexdigest()


def run_key(store_id: str, seed: int, experiment: str, method: str, config_json: str) -> bytes:
    """The key every record of a run store is bound with."""
    parts = [b"ilcforce.store binding 1", str(store_id).encode(), str(int(seed)).encode(),
             str(experiment).encode("utf-8", "surrogatepass"), str(method).encode("utf-8", "surrogatepass"),
             config_digest(config_json, method).encode()]
    return hashlib.sha256(b"".join(map(_field, parts))).digest()


def _number(value) -> bytes:
    return np.float64(value).tobytes()


def iteration_binding(key: bytes, j: int, status: str, diverged_time: float, diverged_reason: str,
                      fallback_count: int, datasets: Iterable[tuple[str, tuple[int, ...], int]]) -> str:
    """``binding_sha256`` of iteration ``j``: its attributes and, per dataset (name, shape, CRC-32), in
    the order of the group's ``crc32_datasets``."""
    digest = hashlib.sha256(_field(key) + _field(b"iteration") + _field(str(int(j)).encode()))
    digest.update(_field(str(status).encode("utf-8", "surrogatepass")) + _field(_number(diverged_time))
                  + _field(str(diverged_reason).encode("utf-8", "surrogatepass"))
                  + _field(str(int(fallback_count)).encode()))
    for name, shape, crc in datasets:
        digest.update(_field(str(name).encode("utf-8", "surrogatepass"))
                      + _field(str(tuple(int(n) for n in shape)).encode())
                      + struct.pack("<I", int(crc) & 0xFFFFFFFF))
    return digest.hexdigest()


def data_binding(key: bytes, place: str, arrays: Iterable[tuple[str, np.ndarray]]) -> str:
    """The binding of datasets written once (``/reference`` and ``/control_time``): sha256 of the key,
    the place and each dataset's name, shape and bytes (float64, little-endian)."""
    digest = hashlib.sha256(_field(key) + _field(place.encode()))
    for name, array in arrays:
        array = np.ascontiguousarray(array, dtype="<f8")
        digest.update(_field(name.encode()) + _field(str(array.shape).encode()))
        digest.update(array.tobytes())
    return digest.hexdigest()


def reference_arrays(reference: dict[str, np.ndarray], control_time: np.ndarray | None
                     ) -> list[tuple[str, np.ndarray]]:
    """What the binding of ``/reference`` covers: each reference signal (by name, sorted) and the
    control grid (``/control_time``) when the store has one."""
    arrays = [(f"reference/{name}", reference[name]) for name in sorted(reference)]
    return arrays + ([("control_time", control_time)] if control_time is not None else [])


def study_key(study_id: str, fingerprint: str, definition_json: str) -> bytes:
    """The key every column of a study store (schema 1.3 on) is bound with."""
    parts = [b"ilcforce.study binding 1", str(study_id).encode(), str(fingerprint).encode("utf-8", "surrogatepass"),
             str(definition_json).encode("utf-8", "surrogatepass")]
    return hashlib.sha256(b"".join(map(_field, parts))).digest()


def column_binding(key: bytes, path: str, seal: object) -> str:
    """``binding_sha256`` of a study column: sha256 of the study's key, the column's path and its seal
    (its ``data_sha256``, or its ``strings_crc32``), which covers every value already."""
    return hashlib.sha256(_field(key) + _field(path.encode()) + _field(str(seal).encode())).hexdigest()
