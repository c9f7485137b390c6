"""cevm.sniff: the text-sniffing rules shared by the logger reader and the cycle reader."""

from __future__ import annotations

import codecs

import pytest

from cevm.errors import InputError
from cevm.sniff import looks_binary, not_text_reason, sniff_bom, utf16_hint, utf16_without_bom

TEXT = "time_s,speed_kmh\n0,0\n1,2.5\n2,5.0\n3,7.5\n4,10\n"


def test_byte_order_marks_name_their_encoding():
    assert sniff_bom(codecs.BOM_UTF8 + b"a") == ("utf-8", 3)
    assert sniff_bom(codecs.BOM_UTF32_LE + b"a") == ("utf-32-le", 4)  # FF FE 00 00: not UTF-16 LE
    assert sniff_bom(codecs.BOM_UTF16_LE + b"a\x00") == ("utf-16-le", 2)
    assert sniff_bom(codecs.BOM_UTF16_BE + b"\x00a") == ("utf-16-be", 2)
    assert sniff_bom(b"time_s") is None


def test_binary_is_a_nul_or_more_than_one_percent_controls():
    assert not looks_binary(TEXT.encode())
    assert looks_binary(b"abc\x00def")
    assert not looks_binary(b"a" * 200 + b"\x1a")  # one control in 201 bytes
    assert looks_binary(b"a" * 90 + b"\x01\x02")  # two in 92


def test_utf16_without_a_mark_is_named():
    assert utf16_without_bom(TEXT.encode("utf-16-le")) == "utf-16-le"
    assert utf16_without_bom(TEXT.encode("utf-16-be")) == "utf-16-be"
    assert utf16_without_bom(TEXT.encode()) is None
    assert "csv.encoding = 'utf-16-le'" in utf16_hint(TEXT.encode("utf-16-le"))


def test_not_text_reasons():
    assert not_text_reason(TEXT.encode(), "cycle file") is None
    assert not_text_reason(codecs.BOM_UTF8 + TEXT.encode(), "cycle file") is None  # UTF-8 with a BOM is text
    assert not_text_reason(TEXT.encode("utf-16"), "cycle file") == (
        "UTF-16-LE text (its byte order mark says so): save the cycle file as UTF-8")
    why = not_text_reason(TEXT.encode("utf-16-le"), "cycle file")
    assert why == ("binary data, not a cycle file (CSV text) (it looks like UTF-16-LE text without a byte order "
                   "mark: save it as UTF-8)")


def test_the_cycle_reader_refuses_utf16_by_its_mark(tmp_path):
    from cevm.io import read_cycle_csv

    p = tmp_path / "c.csv"
    p.write_bytes(TEXT.encode("utf-16"))
    with pytest.raises(InputError, match=r"UTF-16-LE text \(its byte order mark says so\): save the cycle file as"):
        read_cycle_csv(p)
