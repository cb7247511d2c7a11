"""What a model file names, checked before MuJoCo reads any of it (docs/model.md#model-file-limits).

MuJoCo opens every file a model names by itself, blocking on a FIFO and reading a device without end,
and its parse takes time growing with the square of the elements (120,000 empty bodies: 205 s). So
:func:`scan_model` goes first, in time bounded by the limits below:

* every XML file of the model, the file itself and its ``<include file>`` (recursively, at every place
  MuJoCo looks for one: beside the model file and beside the including file), and the MJCF of every
  ``<model file>`` asset, is read by ilcforce's one safe open (:func:`ilcforce.tomlfile.read_regular`:
  a regular file, never waited on) and scanned by expat with entity declarations refused (MuJoCo does
  not expand them; a billion-laughs file would make expat do so);
* every asset (``<mesh file>``, ``<hfield file>``, ``<skin file>``, ``<texture file>`` and the six
  cube faces ``fileright`` .. ``fileback``) is checked by name (:func:`ilcforce.tomlfile.check_regular`)
  at every place MuJoCo may look for it (the model's folder and the naming file's, with and without
  ``meshdir``, ``texturedir`` and ``assetdir``, with and without its folders as ``strippath`` drops
  them): a regular file, at most :data:`MAX_ASSET_BYTES`, all together at most
  :data:`MAX_ASSETS_BYTES`; a PNG texture or height field and a builtin one at most :data:`MAX_PIXELS`;
* the bodies (after ``<replicate>`` and ``<attach>``), the elements, and the counts of ``<size>`` that
  MuJoCo allocates per body or per keyframe are bounded; deformable bodies (``flex``, ``flexcomp``,
  whose counts make bodies without bound) are refused: they are no part of a rigid serial arm.

A URDF names no file MuJoCo opens here: its meshes are deleted before compiling
(:mod:`ilcforce.plants.model_file`), so a mesh that is a FIFO, missing or huge changes nothing.
"""

from __future__ import annotations

import os
import stat
from dataclasses import dataclass, field
from pathlib import Path
from xml.parsers import expat

from ilcforce.tomlfile import UnreadableFile, check_regular, read_regular

#: All XML of one model (the file, its includes and the MJCF of its model assets), bytes. The shipped
#: models are 1.3-2.3 kB; a robot's MJCF with every part included is some hundred kB.
MAX_XML_BYTES = 4 << 20
#: XML files of one model (the file and its includes, recursively).
MAX_XML_FILES = 256
#: One asset file (a mesh, texture, height field or skin), bytes: an OBJ mesh of 500,000 vertices and
#: faces is 23 MB and takes MuJoCo 4.3 s (measured); a robot's meshes are a few MB each.
MAX_ASSET_BYTES = 32 << 20
#: All asset files of one model together, bytes.
MAX_ASSETS_BYTES = 128 << 20
#: Bodies, after every ``<replicate>`` and ``<attach>``: a serial arm has a few; MuJoCo parses 8,000
#: empty bodies in 0.37 s and 16,000 in 2.2 s (the time goes with the square).
MAX_BODIES = 1_000
#: Elements (bodies, geoms, sites, joints, ...), after every ``<replicate>``: 20,000 sites parse in 0.44 s,
#: 80,000 in 13.7 s.
MAX_ELEMENTS = 20_000
#: Pixels of one texture or height field (a PNG's header, or a builtin's width x height, nrow x ncol):
#: MuJoCo allocates them whole, whatever the file's size (a 1 kB PNG may say 100,000 x 100,000).
MAX_PIXELS = 4096 * 4096
#: Files named as assets (each looked for at up to 72 places), and different ``meshdir``, ``texturedir``
#: and ``assetdir`` values: a robot has some dozens of meshes and one folder of them; without these
#: bounds 10,000 compiler elements and 10,000 textures (within the element bound) made 1e10 look-ups.
MAX_ASSET_NAMES = 2_000
MAX_DIRS = 8
#: The largest ``<size>`` counts: MuJoCo allocates nuser_body numbers per body (1e8: 10 s and 800 MB
#: per body) and a state per keyframe.
MAX_SIZE_COUNTS = {"nkey": 1_000, "nuserdata": 1_000_000}
MAX_USER_NUMBERS = 1_000  # each nuser_*

#: MJCF elements naming a file MuJoCo opens, and the attributes that name it.
ASSET_FILES = {"mesh": ("file",), "hfield": ("file",), "skin": ("file",),
               "texture": ("file", "fileright", "fileleft", "fileup", "filedown", "filefront", "fileback")}
_DIRS = ("meshdir", "texturedir", "assetdir")
_PNG = b"\x89PNG\r\n\x1a\n"


class ModelFileError(ValueError):
    """A model file that cannot be a plant: one line naming the problem."""


@dataclass
class _Budget:  # what one model and everything it names have used so far
    xml_bytes: int = 0
    xml_files: int = 0
    asset_bytes: int = 0
    assets: set = field(default_factory=set)


@dataclass
class Scan:
    """What :func:`scan_model` found: whether the file is a URDF, every file MuJoCo may read (the
    model's XML files and the assets that exist), the bodies and elements MuJoCo will make."""

    path: Path
    urdf: bool = False
    files: list[Path] = field(default_factory=list)
    bodies: int = 0
    elements: int = 0
    attaches: int = 0
    dirs: list[str] = field(default_factory=list)
    assets: list[tuple[str, str, str, Path]] = field(default_factory=list)  # (element, attribute, value, folder)
    models: list[tuple[str, Path]] = field(default_factory=list)  # <model file> assets: (value, folder)


def _refuse(path, reason: str) -> ModelFileError:
    return ModelFileError(f"{path}: {reason}")


def _count(scan: Scan, path: Path, what: str, add: int) -> None:
    if what == "bodies":
        scan.bodies += add
        if scan.bodies > MAX_BODIES:
            raise _refuse(path, f"more than {MAX_BODIES:,} bodies (after <replicate> and <attach>); a serial arm "
                                "has a few, and MuJoCo's parse time grows with the square of the count")
    else:
        scan.elements += add
        if scan.elements > MAX_ELEMENTS:
            raise _refuse(path, f"more than {MAX_ELEMENTS:,} elements (after <replicate>); MuJoCo's parse time "
                                "grows with the square of the count")


def _number(value, default: int = 1) -> int:
    try:
        return int(str(value).strip())
    except ValueError:
        return default  # MuJoCo names what it cannot read


def _scan_xml(scan: Scan, file: Path, budget: _Budget, chain: tuple[str, ...], multiplier: int, main: bool,
              top: bool) -> None:
    """Read one XML file of the model safely and count and collect what it holds (``main``: the model
    file the user named; ``top``: a model, whose root element says URDF or MJCF, not an include)."""
    real = os.path.realpath(file)
    if real in chain:
        raise _refuse(chain[0], f"{file} includes itself (through <include>)")
    budget.xml_files += 1
    if budget.xml_files > MAX_XML_FILES:
        raise _refuse(chain[0] if chain else file, f"names more than {MAX_XML_FILES} XML files through <include>")
    try:
        data = read_regular(file, MAX_XML_BYTES - budget.xml_bytes)
    except UnreadableFile as exc:
        reason = str(exc)
        if reason.startswith("is larger than"):
            reason = f"is larger than the {MAX_XML_BYTES >> 20} MB of XML a model may have (with its includes)"
        if main:
            raise _refuse(file, "no such model file" if reason == "does not exist" else reason) from None
        raise _refuse(chain[0], f"names {file}, which {reason}") from None
    budget.xml_bytes += len(data)
    scan.files.append(Path(file))
    folder = Path(file).absolute().parent
    stack = [multiplier]
    includes: list[tuple[str, int]] = []

    def start(tag: str, attrs: dict) -> None:
        times = stack[-1]
        if tag == "replicate":
            times *= max(1, _number(attrs.get("count")))
        stack.append(times)
        if top and len(stack) == 2:
            scan.urdf = tag == "robot"
        _count(scan, file, "elements", times)
        if tag == ("link" if scan.urdf else "body"):
            _count(scan, file, "bodies", times)
        if scan.urdf:
            return
        if tag in ("flex", "flexcomp"):
            raise _refuse(file, f"<{tag}> is a deformable body, not part of a rigid serial arm")
        if tag == "include" and "file" in attrs:
            includes.append((attrs["file"], times))
        elif tag == "compiler":
            scan.dirs = list(dict.fromkeys(scan.dirs + [attrs[d] for d in _DIRS if attrs.get(d)]))
            if len(scan.dirs) > MAX_DIRS:
                raise _refuse(file, f"more than {MAX_DIRS} different meshdir, texturedir and assetdir values")
        elif tag == "model" and "file" in attrs:
            scan.models.append((attrs["file"], folder))
        elif tag == "attach":
            scan.attaches += times
        elif tag == "size":
            for key, value in attrs.items():
                most = MAX_SIZE_COUNTS.get(key, MAX_USER_NUMBERS if key.startswith("nuser_") else None)
                if most is not None and _number(value, 0) > most:
                    raise _refuse(file, f"<size {key}=\"{value[:20]}\"> is more than {most:,}")
        if tag in ASSET_FILES:
            scan.assets += [(tag, name, attrs[name], folder) for name in ASSET_FILES[tag] if attrs.get(name)]
            if len(scan.assets) > MAX_ASSET_NAMES:
                raise _refuse(file, f"names more than {MAX_ASSET_NAMES:,} asset files")
        pixels = {"texture": ("width", "height"), "hfield": ("nrow", "ncol")}.get(tag)
        if pixels and _number(attrs.get(pixels[0]), 0) * _number(attrs.get(pixels[1]), 0) > MAX_PIXELS:
            raise _refuse(file, f"<{tag}> of {attrs[pixels[0]][:12]} x {attrs[pixels[1]][:12]} is more than "
                                f"{MAX_PIXELS:,} pixels")

    def entity(name, *_args) -> None:
        raise _refuse(file, f"declares the XML entity {name!r}; a model file may not (MuJoCo does not expand "
                            "entities, and expanding them can take memory without bound)")

    # as MuJoCo's parser reads it: UTF-8 whatever the declaration says, a stray byte no error, an entity
    # it does not know (&nbsp;) skipped (a "foreign DTD" might define it; none is ever loaded)
    parser = expat.ParserCreate(encoding="utf-8")
    parser.SetParamEntityParsing(expat.XML_PARAM_ENTITY_PARSING_NEVER)
    parser.UseForeignDTD(True)
    parser.StartElementHandler = start
    parser.EndElementHandler = lambda tag: stack.pop()
    parser.EntityDeclHandler = entity
    try:
        parser.Parse(data.decode("utf-8", errors="replace"), True)
    except expat.ExpatError as exc:
        raise _refuse(file, f"not well-formed XML ({expat.ErrorString(exc.code)}, line {exc.lineno})") from None
    root = Path(chain[0]).parent if chain else folder
    for name, times in includes:  # MuJoCo looks beside the model file, and beside the including file
        seen = set()
        for candidate in (root / name, folder / name):
            if os.path.lexists(candidate) and os.path.realpath(candidate) not in seen:
                seen.add(os.path.realpath(candidate))
                _scan_xml(scan, candidate, budget, chain + (real,) if chain else (str(file), real), times, False, False)


def _png_pixels(path: Path) -> int | None:
    """width x height of a PNG file (its header), None for any other file."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        head = os.pread(fd, 24, 0)
    finally:
        os.close(fd)
    if len(head) < 24 or not head.startswith(_PNG):
        return None
    return int.from_bytes(head[16:20], "big") * int.from_bytes(head[20:24], "big")


def _candidates(value: str, folder: Path, root: Path, dirs: list[str]) -> list[Path]:
    """Every place MuJoCo may open the asset ``value`` named in a file in ``folder`` of the model in ``root``."""
    relative = os.path.relpath(folder, root)
    found = []
    for name in dict.fromkeys((value, os.path.basename(value))):
        for base in dict.fromkeys((root, folder)):
            for prefix in ("", *dirs):
                for sub in dict.fromkeys(("", relative)):
                    found.append(Path(os.path.join(base, prefix, sub, name)))
    return list(dict.fromkeys(found))


def _check_assets(scan: Scan, budget: _Budget) -> None:
    root = scan.path.absolute().parent
    for tag, attribute, value, folder in scan.assets:
        for candidate in _candidates(value, folder, root, scan.dirs):
            if not os.path.lexists(candidate):
                continue
            try:
                info = check_regular(candidate, MAX_ASSET_BYTES)
            except UnreadableFile as exc:
                raise _refuse(scan.path, f"<{tag} {attribute}=\"{value[:200]}\">: {candidate} {exc}") from None
            key = (info.st_dev, info.st_ino)
            if key not in budget.assets:
                budget.assets.add(key)
                budget.asset_bytes += info.st_size
                if budget.asset_bytes > MAX_ASSETS_BYTES:
                    raise _refuse(scan.path, f"its assets are larger than {MAX_ASSETS_BYTES >> 20} MB together")
                scan.files.append(candidate)
            if tag in ("texture", "hfield") and (_png_pixels(candidate) or 0) > MAX_PIXELS:
                raise _refuse(scan.path, f"<{tag} {attribute}=\"{value[:200]}\">: {candidate} is an image of more than "
                                         f"{MAX_PIXELS:,} pixels")


def _scan(path: Path, budget: _Budget, chain: tuple[str, ...]) -> Scan:
    scan = Scan(Path(path))
    _scan_xml(scan, Path(path), budget, chain, 1, not chain, True)
    if scan.urdf:
        return scan
    _check_assets(scan, budget)
    root = scan.path.absolute().parent
    for value, folder in scan.models:  # an MJCF whose bodies <attach> copies (each time)
        for candidate in _candidates(value, folder, root, scan.dirs):
            if os.path.lexists(candidate):
                if os.path.realpath(candidate) in chain:
                    raise _refuse(chain[0], f"{candidate} names itself (through <model>)")
                inner = _scan(candidate, budget, (*chain, os.path.realpath(path)) if chain else
                              (str(path), os.path.realpath(path)))
                scan.files += inner.files
                _count(scan, scan.path, "bodies", inner.bodies * max(1, scan.attaches))
                _count(scan, scan.path, "elements", inner.elements * max(1, scan.attaches))
    return scan


def scan_model(path: Path | str) -> Scan:
    """Check the model file ``path`` and every file it names before MuJoCo reads any (module docstring);
    :class:`ModelFileError` (one line) naming the file and the problem otherwise."""
    return _scan(Path(path), _Budget(), ())
