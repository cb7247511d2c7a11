"""Per-iteration groups stamped from a template: the cheap way to write thousands of attributes.

Every iteration group has the same datasets with the same ``units`` / ``description`` / ``axes``
attributes. Writing those with h5py costs about 0.1-0.5 ms per attribute (measured: 7,224
attribute writes took about 1 s for the paper's c3 x 20 store), so the writer builds the group
once in an in-memory HDF5 file and copies it (HDF5's H5Ocopy, attributes included, in C) into
the store per iteration, then fills in the data.

Checksums: the iteration datasets are contiguous and unfiltered (HDF5's Fletcher-32 doubled the
write time of the 2 MB an iteration holds); instead the group carries ``crc32`` (uint32, one per
dataset, zlib.crc32 of the C-order float64 bytes) in the order of its ``crc32_datasets``
attribute. Readers verify the checksum of everything they read.
"""

from __future__ import annotations

import zlib
from collections.abc import Mapping

import h5py
import numpy as np

from ilcforce.store import schema
from ilcforce.store.seal import seal_attrs

_NAME = b"iteration"


def crc32(array: np.ndarray) -> int:
    """zlib.crc32 of the C-order float64 bytes of ``array``."""
    return zlib.crc32(np.ascontiguousarray(array, dtype=np.float64).data) & 0xFFFFFFFF


MemorySpec = tuple[tuple[str, tuple[int, ...], str, tuple[str, ...] | None], ...]


class IterationTemplate:
    """An iteration group (log + memory datasets with their attributes, no data) to copy; the log of
    a task of ``dimension`` axes (:func:`ilcforce.store.schema.log_datasets`)."""

    def __init__(self, n_log: int, memory: MemorySpec, dimension: int = schema.DEFAULT_TASK_DIMENSION) -> None:
        self.n_log = n_log
        self.memory = memory
        self.dimension = dimension
        self.signals = schema.log_datasets(dimension)
        self.names = [f"log/{s}" for s in self.signals] + [f"memory/{m[0]}" for m in memory]
        self.sums: list[int] = []
        self._file = h5py.File(f"ilcforce-template-{id(self)}", "w", driver="core", backing_store=False,
                               libver=schema.LIBVER)
        group = self._file.create_group(_NAME.decode())
        group.attrs["crc32_datasets"] = self.names
        log = group.create_group("log")
        for signal, (axes, unit, description) in self.signals.items():
            self._dataset(log, signal, schema.signal_shape(axes, n_log), unit, description, "axes", axes)
        memory_group = group.create_group("memory")
        for name, shape, unit, columns in memory:
            self._dataset(memory_group, name, shape, unit,
                          f"learned memory {name} after this iteration (the memory the next iteration starts "
                          "from), on the control grid /control_time", "columns", columns)

    @staticmethod
    def _dataset(group: h5py.Group, name: str, shape: tuple[int, ...], unit: str, description: str,
                 label_attr: str, labels: tuple[str, ...] | None) -> None:
        dataset = group.create_dataset(name, shape=shape, dtype=np.float64)
        dataset.attrs["units"] = unit
        dataset.attrs["description"] = description
        if labels is not None:
            dataset.attrs[label_attr] = list(labels)
        seal_attrs(dataset)  # copied with the dataset into every iteration

    def stamp(self, handle: h5py.File, path: str, log: Mapping[str, np.ndarray],
              memory: Mapping[str, np.ndarray]) -> h5py.Group:
        """Copy the template to ``path`` in ``handle`` and write the data and its checksums."""
        h5py.h5o.copy(self._file.id, _NAME, handle.id, path.encode())
        # h5py's low-level API: a dataset opened and written whole by H5Dopen/H5Dwrite costs about a
        # third of Group[...] + Dataset.write_direct (their selection machinery), for the same bytes
        group_id = h5py.h5g.open(handle.id, path.encode())
        sums = np.empty(len(self.names), dtype=np.uint32)
        k = 0
        for folder, items in ((b"log", ((s, log[s]) for s in self.signals)),
                              (b"memory", ((m[0], memory[m[0]]) for m in self.memory))):
            folder_id = h5py.h5g.open(group_id, folder)
            for name, data in items:
                data = np.ascontiguousarray(data, dtype=np.float64)
                dataset_id = h5py.h5d.open(folder_id, name.encode())
                if dataset_id.shape != data.shape:
                    raise ValueError(f"{folder.decode()}/{name} has shape {data.shape}, the store expects "
                                     f"{dataset_id.shape}")
                dataset_id.write(h5py.h5s.ALL, h5py.h5s.ALL, data)
                sums[k] = crc32(data)
                k += 1
        group = handle[path]
        group.attrs["crc32"] = sums
        self.sums = sums.tolist()  # the last stamp's, in the order of :attr:`names`
        return group

    def close(self) -> None:
        self._file.close()


def verify(group: h5py.Group, relative: str, data: np.ndarray, path: object) -> None:
    """Check ``data`` read from ``group/relative`` against the group's checksum (schema >= 2)."""
    from ilcforce.store.safeio import StoreError

    names = group.attrs.get("crc32_datasets")
    sums = group.attrs.get("crc32")
    if names is None and sums is None:
        raise StoreError(f"{path}: {group.name} has no checksums (attributes crc32, crc32_datasets)")
    try:
        names = [n.decode() if isinstance(n, bytes) else str(n) for n in names]
        sums = np.asarray(sums)
        if sums.dtype.kind not in "iu" or sums.shape != (len(names),):
            raise ValueError
        index = names.index(relative)
    except (TypeError, ValueError):
        raise StoreError(f"{path}: {group.name} has malformed checksums or none for {relative}") from None
    if crc32(data) != int(sums[index]):
        raise StoreError(f"{path}: checksum mismatch in {group.name}/{relative}: the data is damaged")
