"""The files a command writes or reads besides the ones it names, so that none is replaced by
surprise: meshio keeps an XDMF file's arrays in an HDF5 file of the same stem beside it, so
writing ``beam.xdmf`` also writes ``beam.h5`` (and reading it reads ``beam.h5``)."""

import hashlib
import tempfile
from pathlib import Path

from ..errors import ConfigError

XDMF_SUFFIXES = (".xdmf", ".xmf")


def with_data_file(path):
    """``[path]``, and for an XDMF file (``.xdmf``, ``.xmf``) also the ``.h5`` file beside it that
    holds its arrays when meshio writes it."""
    path = Path(path)
    return [path, path.with_suffix(".h5")] if path.suffix.lower() in XDMF_SUFFIXES else [path]


def input_clash(outputs, inputs):
    """The first ``(output, input_file, input)`` where writing ``output`` would replace
    ``input_file``, the file ``input`` names or its XDMF data file; None if none would.
    outputs, inputs: paths; empty inputs (None, "") are skipped."""
    read = {}
    for name in inputs:
        if name:
            for file in with_data_file(name):
                read.setdefault(file.resolve(), (file, name))
    for output in outputs:
        hit = read.get(Path(output).resolve())
        if hit is not None:
            return (output, *hit)
    return None


def describe_input(input_file, name):
    """``'beam.vtu'``, or ``'beam.h5' (the data of 'beam.xdmf')`` for an XDMF file's data file."""
    if Path(input_file).resolve() == Path(name).resolve():
        return f"'{name}'"
    return f"'{input_file}' (the data of '{name}')"


def read_files(path):
    """The files a reader of the mesh file ``path`` reads: ``[path]``, and for an XDMF file the
    files its data items name as meshio finds them: ``Format="HDF"`` (``beam.h5:/data0``) relative
    to the folder of the file a link points to, ``Format="Binary"`` relative to the working folder;
    where it cannot be parsed, the ``.h5`` beside it (``with_data_file``) if that exists."""
    path = Path(path)
    if path.suffix.lower() not in XDMF_SUFFIXES:
        return [path]
    import xml.etree.ElementTree as ElementTree

    try:
        root = ElementTree.parse(path).getroot()
    except (ElementTree.ParseError, LookupError, ValueError):    # not XML, or an unknown encoding
        return [file for file in with_data_file(path) if file == path or file.is_file()]
    folder = path.resolve().parent
    named = set()
    for item in root.iter("DataItem"):
        text = (item.text or "").strip()
        if not text or item.get("ItemType") == "Reference":
            continue
        if item.get("Format") == "HDF":
            named.add(folder / text.split(":", 1)[0])
        elif item.get("Format") == "Binary":
            named.add(Path(text))
    return [path, *sorted(named)]


def content_sha256(path):
    """SHA-256 (hex) of the bytes of ``read_files(path)`` one after the other: what a reader of the
    mesh file gets (of a file that is not XDMF, ``sha256sum``'s)."""
    digest = hashlib.sha256()
    for file in read_files(path):
        with open(file, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                digest.update(chunk)
    return digest.hexdigest()


def writable_folder(folder, option="-o"):
    """``folder`` as a ``Path``, made if needed and checked writable (a file written and removed),
    before a report's runs: ``ConfigError`` naming ``option`` and the reason otherwise."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise ConfigError(f"{option} = '{folder}': cannot write there ({exc.strerror or exc})") from None
    return folder
