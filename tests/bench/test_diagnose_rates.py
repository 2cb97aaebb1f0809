"""bench/diagnose_rates.py's converter-fed cases without their minutes: jobs, variants, table."""

from __future__ import annotations

from bench.diagnose_rates import APART, converter_jobs, converter_table, main


def test_variants_make_their_own_jobs_and_rows(capsys):
    todo = converter_jobs(1, 6.0, [2000.0], ["clean p12", "brush_drop 1 V"], ["standard", "skew"])
    # clean twice (configured or not), the effect once; per variant
    assert len(todo) == 6
    assert (
        sorted(j.get("drive_variant", "standard") for j in todo) == ["skew"] * 3 + ["standard"] * 3
    )
    rows = [
        dict(j, verdict="unexplained", chain=["channel_skew"], right=True, seconds=1.0)
        for j in todo
    ]
    text = converter_table(rows)
    assert "skew" in APART
    # a healthy motor behind channels set apart is right with the chain's answer
    assert "| clean p12, skew | a chain finding, no motor effect | no | 1/1 |" in text
    # told, the chain is modelled: `none` is right again
    assert "| clean p12, skew | `none` | yes |" in text
    assert "| clean p12 | `none` | no | 1/1 |" in text
    assert "| brush_drop 1 V, skew | the effect |" in text
    assert main(["--drive", "realistic", "--variants", "warp", "--cases", "clean p12"]) == 2
    assert "unknown warp" in capsys.readouterr().err
