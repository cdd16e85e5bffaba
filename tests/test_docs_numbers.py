"""Numbers the documentation states about the shipped models are the models' own: the
parameter counts in README.md and docs/MODEL_ZOO.md are counted here."""

from __future__ import annotations

from pathlib import Path

from prosplat import ProSplat

ROOT = Path(__file__).resolve().parents[1]


def test_documented_parameter_counts_match_the_shipped_models():
    from prosplat.improve.io import DEFAULT_IMPROVE_WEIGHTS, load_improver

    improver = sum(p.numel() for p in load_improver(DEFAULT_IMPROVE_WEIGHTS).parameters())
    generator = sum(
        p.numel() for p in ProSplat.from_pretrained(improve=False).generator.parameters()
    )
    readme = (ROOT / "README.md").read_text()
    zoo = (ROOT / "docs" / "MODEL_ZOO.md").read_text()
    assert f"The `tiny` model ({improver:,} parameters)" in readme
    assert f"The `tiny` improvement model ({improver:,} parameters" in zoo
    assert f"The `tiny` generator ({generator:,} parameters)" in zoo
