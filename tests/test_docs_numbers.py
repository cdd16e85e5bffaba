"""Numbers the documentation states about the shipped models are the models' own: the
parameter counts in README.md and prosplat/weights/README.md are counted here."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_documented_parameter_counts_match_the_shipped_models():
    from prosplat.improve.io import DEFAULT_IMPROVE_WEIGHTS, load_improver
    from prosplat.pipeline.model import ProSplat

    improver = sum(p.numel() for p in load_improver(DEFAULT_IMPROVE_WEIGHTS).parameters())
    generator = sum(
        p.numel() for p in ProSplat.from_pretrained(improve=False).generator.parameters()
    )
    readme = (ROOT / "README.md").read_text()
    weights = (ROOT / "prosplat" / "weights" / "README.md").read_text()
    assert f"The `tiny` model ({improver:,} parameters)" in readme
    assert f"The `tiny` improvement model ({improver:,} parameters" in weights
    assert f"The `tiny` generator ({generator:,} parameters)" in weights
