"""Weight blending of two improvement models (prosplat.train.blend, `prosplat train blend`)."""

from __future__ import annotations

import pytest
import torch
from improve_configs import SMALL

from prosplat.cli import main
from prosplat.improve.config import ImproveConfig
from prosplat.improve.io import load_improver, save_improver
from prosplat.improve.model import ImproveModel
from prosplat.train.blend import blend_improvers


def _pair(config: ImproveConfig = SMALL) -> tuple[ImproveModel, ImproveModel]:
    torch.manual_seed(0)
    a = ImproveModel(config)
    torch.manual_seed(1)
    b = ImproveModel(config.with_(working_size=config.working_size + 64))
    return a.eval(), b.eval()


def test_blend_interpolates_every_weight_and_keeps_a_working_size() -> None:
    a, b = _pair()
    sa, sb = a.state_dict(), b.state_dict()
    assert any(not torch.equal(sa[k], sb[k]) for k in sa)
    for w in (0.0, 0.3, 1.0):
        sm = blend_improvers(a, b, w).state_dict()
        for k, v in sa.items():
            if v.is_floating_point():
                torch.testing.assert_close(sm[k], (1 - w) * v + w * sb[k], rtol=1e-6, atol=1e-7)
            else:
                assert torch.equal(sm[k], v)
    assert blend_improvers(a, b, 0.5).config == a.config


def test_blend_at_the_ends_is_the_model_itself() -> None:
    a, b = _pair()
    x = torch.rand(1, 3, 32, 32)
    ref = torch.rand(1, 3, 32, 32)
    fund = torch.eye(3, dtype=torch.float64)[None]
    with torch.no_grad():
        torch.testing.assert_close(blend_improvers(a, b, 0.0)(x, ref, fund), a(x, ref, fund))
        torch.testing.assert_close(blend_improvers(a, b, 1.0)(x, ref, fund), b(x, ref, fund))


def test_blend_refuses_other_architectures_and_weights_outside_0_1() -> None:
    a, _ = _pair()
    other = ImproveModel(SMALL.with_(cross_attention_dim=32))
    with pytest.raises(ValueError, match="cross_attention_dim"):
        blend_improvers(a, other, 0.5)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        blend_improvers(a, a, 1.5)


def test_cli_blend_writes_a_loadable_file_and_does_not_clobber(tmp_path, capsys) -> None:
    a, b = _pair()
    pa = save_improver(a, tmp_path / "a.safetensors")
    pb = save_improver(b, tmp_path / "b.safetensors")
    out = tmp_path / "mid.safetensors"
    with pytest.raises(SystemExit) as done:
        main(["train", "blend", str(pa), str(pb), "--weight", "0.25", "--out", str(out)])
    assert done.value.code == 0
    mid = load_improver(out)
    k = next(k for k, v in a.state_dict().items() if v.is_floating_point())
    torch.testing.assert_close(
        mid.state_dict()[k], 0.75 * a.state_dict()[k] + 0.25 * b.state_dict()[k]
    )
    before = out.read_bytes()
    with pytest.raises(SystemExit) as done:
        main(["train", "blend", str(pa), str(pb), "--weight", "0.5", "--out", str(out)])
    assert done.value.code == 2
    assert "exists" in capsys.readouterr().err
    assert out.read_bytes() == before


def test_cli_blend_fill_input_joins_a_fill_fine_tune_with_its_start(tmp_path, capsys) -> None:
    """A model fine-tuned with --fill (config fill_input) and the one it started from differ
    in config, so a plain blend refuses them; --fill-input loads both as fill models."""
    a, b = _pair()
    pa = save_improver(a, tmp_path / "start.safetensors")
    pb = save_improver(
        load_improver(save_improver(b, tmp_path / "b.safetensors"), fill_input=True),
        tmp_path / "fill.safetensors",
    )
    out = tmp_path / "mid.safetensors"
    argv = ["train", "blend", str(pa), str(pb), "--weight", "0.5", "--out", str(out)]
    with pytest.raises(SystemExit) as done:
        main(argv)
    assert done.value.code == 2 and "fill_input" in capsys.readouterr().err
    with pytest.raises(SystemExit) as done:
        main(argv + ["--fill-input"])
    assert done.value.code == 0
    mid = load_improver(out)
    assert mid.config.fill_input
    k = next(k for k, v in a.state_dict().items() if v.is_floating_point())
    torch.testing.assert_close(mid.state_dict()[k], 0.5 * (a.state_dict()[k] + b.state_dict()[k]))
