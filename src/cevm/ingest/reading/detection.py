"""Which logger wrote a file: its profile detected from the first bytes (encoding by
byte order mark, binary data refused), or the profile given."""

from __future__ import annotations

from pathlib import Path

from cevm.errors import InputError
from cevm.ingest.profiles import Profile, load_profiles
from cevm.ingest.reading.header import _find_header
from cevm.ingest.textfile import ByteStream, ReadLimits
from cevm.sniff import ascii_transparent, looks_binary, sniff_bom, utf16_hint
from cevm.text import shorten

#: Bytes read from the start of a file to detect its profile.
_HEAD_BYTES = 65536


def _head_bytes(path: Path, n: int = _HEAD_BYTES) -> bytes:
    """First ``n`` bytes of the (decompressed) file, for detection."""
    with ByteStream(path, ReadLimits()) as raw:
        return raw.peek(n)


def detect_profile(path: str | Path, profiles: dict[str, Profile] | None = None) -> Profile:
    """The profile whose required header columns all appear in the file's header.

    The header is read with each profile's own encoding, comment prefix and separator.
    When several match, the most specific (most required columns) wins; a tie, or no
    match, raises :class:`InputError` listing the profiles and the header found.
    """
    path = Path(path)
    profiles = load_profiles() if profiles is None else profiles
    if not profiles:
        raise InputError(path, "no logger profiles loaded")
    return _detect_in_head(path, _head_bytes(path), profiles)


def _detect_in_head(path: Path, head: bytes, profiles: dict[str, Profile]) -> Profile:
    """:func:`detect_profile` on the first bytes ``head`` of the (decompressed) file.

    A byte order mark decides the encoding for every profile (UTF-16 and UTF-32 text is
    decoded, not called binary); otherwise each profile's own encoding is tried."""
    if not head or head.isspace():
        raise InputError(path, "file is empty", line=1)
    bom = sniff_bom(head)
    if bom is not None:
        enc, n = bom
        head = head[n:].decode(enc, errors="replace").encode("utf-8")
        if not head or head.isspace():
            raise InputError(path, "file is empty", line=1)
    if looks_binary(head):
        raise InputError(path, "binary data, not a CSV text file" + utf16_hint(head), line=1)
    matches: list[Profile] = []
    seen_header: tuple[str, ...] = ()
    ascii_head = head.isascii()
    for prof in profiles.values():
        try:
            if bom is not None or (ascii_head and ascii_transparent(prof.encoding)):
                text = head  # what decoding and re-encoding as UTF-8 would give
            else:
                text = head.decode(prof.encoding, errors="replace").encode("utf-8")
        except LookupError:
            continue
        hdr = _find_header(text, prof.comment_prefix, prof.separator)
        if hdr is None:
            continue
        if len(hdr.names) > len(seen_header):
            seen_header = hdr.names
        if set(prof.required_columns) <= set(hdr.names):
            matches.append(prof)
    if not matches:
        shown = ", ".join(shorten(n, 40) for n in seen_header[:12])  # a name may be a 1 MiB line
        shown = shorten(shown + (", ..." if len(seen_header) > 12 else ""))
        listing = "; ".join(f"{p.name} (needs {', '.join(p.required_columns)})" for p in profiles.values())
        raise InputError(path, f"no logger profile matches the header [{shown}]; profiles: {listing}. "
                               "Add a profile (see configs/loggers) or force one.")
    best = max(len(p.required_columns) for p in matches)
    top = [p for p in matches if len(p.required_columns) == best]
    if len(top) > 1:
        raise InputError(path,
                         f"header matches several profiles equally well: {', '.join(p.name for p in top)}; force one")
    return top[0]


# ======================================================================================
# Reading
# ======================================================================================
def _resolve_profile(path: Path, profile: Profile | str | None,
                     profiles: dict[str, Profile] | None) -> Profile:
    if isinstance(profile, Profile):
        return profile
    if profiles is None:
        profiles = load_profiles()
    if profile is None:
        return detect_profile(path, profiles)
    if profile not in profiles:
        raise InputError(path, f"unknown logger profile {profile!r}; known: {', '.join(sorted(profiles))}")
    return profiles[profile]


def _open_log(path: Path, raw: ByteStream, profile: Profile | str | None,
              profiles: dict[str, Profile] | None) -> Profile:
    """The profile given, or detected from the file's first bytes; a plain file over the
    size limit is refused before anything is read."""
    raw.check_size()
    if profile is None:
        profiles = load_profiles() if profiles is None else profiles
        if not profiles:
            raise InputError(path, "no logger profiles loaded")
        prof = _detect_in_head(path, raw.peek(_HEAD_BYTES), profiles)
    else:
        prof = _resolve_profile(path, profile, profiles)
    return prof
