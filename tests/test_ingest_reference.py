"""The stored trips, vectors and profiles of the shipped sample logs equal a reference
made before the ingest stages were tuned for speed (2026-12-01), to rounding
(see tests/ingest_reference.py)."""

from __future__ import annotations

import json

import pytest

import ingest_reference as ir


@pytest.mark.slow
def test_sample_logs_ingest_as_the_reference(tmp_path):
    ref = json.loads(ir.REFERENCE.read_text())
    changed = {k for k, v in ir.file_hashes().items() if ref["files"].get(k) != v}
    if changed or set(ref["files"]) != set(ir.file_hashes()):
        pytest.fail(f"the sample logs changed since the reference was made ({sorted(changed)[:3]}...): "
                    "regenerate it with the code of a commit known to be right "
                    "(python tests/ingest_reference.py --write)")
    st = ir.ingest_samples(tmp_path / "s.sqlite")
    try:
        got = ir.summarise(st)
    finally:
        st.close()
    assert len(got) == len(ref["trips"]) > 40
    diffs = ir.differences(got, ref["trips"])
    assert not diffs, "\n".join(diffs[:20])


@pytest.mark.slow
def test_the_comparison_sees_a_small_change():
    """The comparison is not blind: a 1 mm change of one elevation or a 1e-4 change of a
    vector sum is a difference."""
    ref = json.loads(ir.REFERENCE.read_text())["trips"]
    tid = sorted(ref)[0]
    got = json.loads(json.dumps(ref))
    assert ir.differences(got, ref) == []
    got[tid]["profile"]["elevation_m"]["at"][5] += 2e-3
    assert any("elevation_m.at" in d for d in ir.differences(got, ref))
    got = json.loads(json.dumps(ref))
    got[tid]["vector"]["s_me"] *= 1 + 1e-4
    assert any("vector.s_me" in d for d in ir.differences(got, ref))
