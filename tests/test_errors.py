"""Tests of cevm.errors: one clear line per error, whatever the file name or value holds."""

from __future__ import annotations

from cevm.errors import InputError, has_control
from cevm.text import printable


def test_input_error_is_one_line_whatever_its_parts_hold():
    err = InputError("logs/a\ncevm: failed: b.csv", "bad value 'x\r\x1b[2J'", line=3, column="col\tumn")
    text = str(err)
    assert "\n" not in text and "\r" not in text and "\x1b" not in text and "\t" not in text
    assert text == "logs/a\\ncevm: failed: b.csv:3: column 'col\\tumn': bad value 'x\\r\\x1b[2J'"


def test_printable_keeps_printable_text_and_control_characters_are_found():
    assert printable("Ølstrøm – café\\path 42") == "Ølstrøm – café\\path 42"
    assert printable("a\x00b\x7fc\x9fd\u2028e\u2029") == "a\\x00b\\x7fc\\x9fd\\u2028e\\u2029"
    assert has_control("EB\r07") and not has_control("EB-07 é")
