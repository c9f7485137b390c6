"""Which DSM rasters cevm may open: local files only, unless remote access is asked for.

A DSM name GDAL resolves itself can make it fetch from any host: a URL
(``https://...``), a network file system name (``/vsicurl/``, ``/vsis3/``, ``/vsigs/``,
``/vsiaz/`` ...), a VRT whose sources are such names (at any depth of nested VRTs), or
a local file that is not a raster at all but a description GDAL follows (a WMS, WMTS or
STAC document, whatever its file name). An operator who runs cevm on other people's
files needs that off, so it is off unless asked for: ``cevm ingest --allow-remote-dsm``,
``IngestOptions(allow_remote_dsm=True)``, ``DsmSampler.open(..., allow_remote=True)`` or
the environment variable ``CEVM_ALLOW_REMOTE_DSM=1``.

Without that permission (:func:`check_local`), a DSM raster must be a local GeoTIFF
(recognised by its first bytes, opened with GDAL's GTiff driver only) or a local VRT
(opened with the VRT driver only) whose every source, recursively, is such a file; a
VRT with Python pixel functions is refused as well (code in a data file). Archive
members (``/vsizip/``, ``/vsitar/``, ``/vsigzip/`` of a local archive) are opened as
GeoTIFF only, and refused as VRT sources (GDAL would open them unchecked). Anything else is
refused with one message naming the file, the reference and how to allow it.
"""

from __future__ import annotations

import os
from pathlib import Path
from xml.etree import ElementTree

from cevm.errors import InputError

__all__ = ["ALLOW_REMOTE_ENV", "check_local", "is_remote", "remote_allowed"]

#: Environment variable that allows remote DSM access when set to 1 (or true, yes, on).
ALLOW_REMOTE_ENV = "CEVM_ALLOW_REMOTE_DSM"

#: GDAL virtual file systems that read local files (archives, memory, parts of a file).
_LOCAL_VSI = ("/vsizip/", "/vsitar/", "/vsigzip/", "/vsi7z/", "/vsirar/", "/vsimem/", "/vsisubfile/",
              "/vsisparse/")

_TIFF_MAGIC = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")  # classic and BigTIFF

#: Elements of a VRT that name a file GDAL opens (and any other ``...Filename``).
_VRT_FILE_TAGS = ("SourceFilename", "SourceDataset")


def _names_a_file(tag) -> bool:
    return isinstance(tag, str) and (tag in _VRT_FILE_TAGS or tag.endswith("Filename"))


def remote_allowed(allow: bool | None = None) -> bool:
    """``allow`` if given, else whether ``CEVM_ALLOW_REMOTE_DSM`` is set to 1 / true."""
    if allow is not None:
        return bool(allow)
    return os.environ.get(ALLOW_REMOTE_ENV, "").strip().lower() in ("1", "true", "yes", "on")


def is_remote(name: str) -> bool:
    """True if GDAL would resolve ``name`` over a network: any ``scheme://`` (but a
    ``vrt://`` of a local file), and any ``/vsi...`` file system that is not a local
    one (an archive inside ``/vsicurl/`` is remote too)."""
    s = name.strip()
    low = s.lower()
    if low.startswith("vrt://"):
        return is_remote(s[len("vrt://"):].split("?", 1)[0])
    if "://" in low:
        return True
    if low.startswith("/vsi"):
        for prefix in _LOCAL_VSI:
            if low.startswith(prefix):
                rest = s[len(prefix):].lstrip("{")
                return is_remote(rest)
        return True  # /vsicurl/, /vsis3/, /vsigs/, /vsiaz/, ... and any we do not know
    return False


def _refuse(shown: str, what: str) -> InputError:
    return InputError(shown, f"{what}: remote DSM access is off; pass --allow-remote-dsm "
                             f"(or set {ALLOW_REMOTE_ENV}=1) to allow it")


def check_local(name: str, shown: str | None = None) -> str:
    """The GDAL driver to open the local raster ``name`` with ("GTiff" or "VRT"), after
    checking that opening it cannot make GDAL fetch anything (see the module
    docstring); :class:`cevm.errors.InputError` otherwise."""
    shown = shown or name
    if is_remote(name):
        raise _refuse(shown, f"{name!r} is a network location")
    if name.lower().startswith("/vsi"):
        return "GTiff"  # a member of a local archive: opened as a GeoTIFF, or not at all
    return _check_file(Path(name), shown, ())


def _sniff(path: Path) -> bytes:
    from cevm.io.inputs import open_regular  # a FIFO or a device refused, never read

    with open_regular(path, "DSM raster") as f:
        return f.read(512)


def _is_vrt(head: bytes) -> bool:
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    if text.startswith(b"<?xml"):
        text = text[text.find(b"?>") + 2:].lstrip() if b"?>" in text else text
    return text.startswith(b"<VRTDataset")


def _check_file(path: Path, shown: str, ancestors: tuple[str, ...]) -> str:
    head = _sniff(path)
    if head.startswith(_TIFF_MAGIC):
        return "GTiff"
    if _is_vrt(head):
        _check_vrt(path, shown, ancestors)
        return "VRT"
    raise InputError(shown, f"cannot open as a raster: {str(path)!r} is neither a GeoTIFF nor a VRT, the formats "
                            "read without --allow-remote-dsm (GDAL may read others as descriptions of remote "
                            f"data, such as WMS or STAC documents; {ALLOW_REMOTE_ENV}=1 allows them)")


def _check_vrt(path: Path, shown: str, ancestors: tuple[str, ...]) -> None:
    key = os.path.realpath(path)
    if key in ancestors:
        raise InputError(shown, f"VRT {str(path)!r} refers to itself")
    ancestors = (*ancestors, key)
    try:
        root = ElementTree.parse(path).getroot()
    except (ElementTree.ParseError, OSError) as exc:
        raise InputError(shown, f"VRT {str(path)!r} is not valid XML: {exc}") from None
    for el in root.iter():
        if str(el.get("PixelFunctionLanguage", "")).lower() == "python" or (
            el.tag == "PixelFunctionLanguage" and (el.text or "").strip().lower() == "python"
        ):
            raise InputError(shown, f"VRT {str(path)!r} holds a Python pixel function (code in a data file): refused")
        if not _names_a_file(el.tag) or not (el.text or "").strip():
            continue  # texts that GDAL does not open (an SRS may hold a URI, harmlessly)
        ref = (el.text or "").strip()
        if is_remote(ref):
            raise _refuse(shown, f"VRT {str(path)!r} refers to {ref!r}")
        if ref.lower().startswith("/vsi"):  # GDAL would open the member by its content, unchecked
            raise _refuse(shown, f"VRT {str(path)!r} refers to an archive member {ref!r}, which cevm cannot check")
        if ref.lower().startswith("vrt://"):
            ref = ref[len("vrt://"):].split("?", 1)[0]
        src = Path(ref)  # relative to the working directory, as GDAL reads it ...
        if str(el.get("relativeToVRT", "0")).strip() == "1":
            src = path.parent / src  # ... or to the VRT's directory
        _check_file(src, shown, ancestors)
