"""Install Requirements installs what the tests ran with: the pinned set matches this
environment (so it cannot drift), the pip commands for CPU and CUDA say exactly that, numpy
is never installed beside Blender's, and the download size comes before anything starts."""

from __future__ import annotations

import importlib.metadata as md
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.blender
pytest.importorskip("bpy")

import addon_support  # noqa: E402, F401 - puts the repository root on sys.path

from addon.core import install, pins  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def test_pins_match_the_tested_environment() -> None:
    """``scripts/pin_requirements.py --check`` regenerates addon/core/pins.py from this
    environment's installed versions: a changed pin or version fails here."""
    res = subprocess.run([sys.executable, str(ROOT / "scripts" / "pin_requirements.py"),
                          "--check"], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert res.returncode == 0, res.stderr
    for name, version in pins.PINS:
        installed = md.version(name).split("+")[0]
        assert installed == version, f"{name}: pinned {version}, tested with {installed}"
    import torch

    assert torch.__version__.split("+")[0] == pins.TORCH_VERSION


def test_pins_cover_the_requirements_and_leave_numpy_to_blender() -> None:
    import tomllib

    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    names = {n.lower() for n, _ in pins.PINS}
    for dep in deps:
        name = dep.split(">")[0].split("=")[0].split("<")[0].strip().lower()
        assert name == "numpy" or name in names, f"{name} is not pinned"
    assert "numpy" not in names
    assert set(pins.WHEEL_MB) == {n for n, _ in pins.PINS}  # every download is estimated
    import numpy

    assert install.version_in_range(numpy.__version__, pins.NUMPY_RANGE)  # the tested one
    assert install.numpy_problem() is None
    # both numpys Blender bundles (4.2-5.0: 1.2x; 5.1+: 2.x) are in range, an untested 3 is not
    for version, ok in (("1.26.4", True), ("2.5.5", True), ("1.23.5", False), ("3.0.0", False)):
        assert install.version_in_range(version, pins.NUMPY_RANGE) == ok, version


def test_cpu_command_takes_the_tested_cpu_torch_without_resolving() -> None:
    torch_cmd, rest = install.pip_commands("/t", "CPU", python="PY", platform="linux")
    assert torch_cmd[:3] == ["PY", "-m", "pip"] and "--no-deps" in torch_cmd
    assert torch_cmd[torch_cmd.index("--index-url") + 1] == "https://download.pytorch.org/whl/cpu"
    assert torch_cmd[-1] == f"torch=={pins.TORCH_VERSION}+cpu"
    assert torch_cmd[torch_cmd.index("--target") + 1] == "/t"
    assert "--no-deps" in rest and "--index-url" not in rest  # the user's usual index
    reqs = [a for a in rest if "==" in a and ";" not in a]
    assert reqs == [f"{n}=={v}" for n, v in pins.PINS if n != "torch"]
    assert not any(a.lower().startswith("numpy") for a in torch_cmd + rest)
    assert any(a.startswith("colorama") and "Windows" in a for a in rest)  # tqdm needs it there
    # macOS: the CPU index has no +cpu label (its wheels are the CPU build anyway)
    mac, _ = install.pip_commands("/t", "CPU", python="PY", platform="darwin")
    assert mac[-1] == f"torch=={pins.TORCH_VERSION}"


def test_cuda_command_lets_torch_pull_its_libraries_at_tested_versions() -> None:
    torch_cmd, rest = install.pip_commands("/t", "CUDA", "--proxy http://p:1", python="PY",
                                           platform="linux", constraints="/c.txt")  # fmt: skip
    assert "--no-deps" not in torch_cmd  # the NVIDIA libraries come as torch's dependencies
    assert "/cu" in torch_cmd[torch_cmd.index("--index-url") + 1]
    assert torch_cmd[torch_cmd.index("--constraint") + 1] == "/c.txt"
    assert torch_cmd[-1] == f"torch=={pins.TORCH_VERSION}"
    assert ["--proxy", "http://p:1"] == torch_cmd[-3:-1] and "--proxy" in rest
    assert "numpy" not in install.constraints_text() and "sympy==" in install.constraints_text()
    with pytest.raises(ValueError, match="torch build"):
        install.pip_commands("/t", "ROCM")


def test_download_size_is_shown_as_an_estimate() -> None:
    cpu, cuda = install.download_estimate_mb("CPU"), install.download_estimate_mb("CUDA")
    assert 100 < cpu < 1000 and cuda > cpu + 1000
    text = install.describe_download("CPU")
    assert "estimate" in text and "MB" in text and pins.TORCH_VERSION in text
    assert "GB" in install.describe_download("CUDA")


@pytest.mark.parametrize(
    ("version", "spec", "ok"),
    [("1.26.4", "<2.0,>=1.24", True), ("1.24", "<2.0,>=1.24", True), ("2.0.0", "<2.0,>=1.24", False),
     ("1.23.5", "<2.0,>=1.24", False), ("1.26.4rc1", ">=1.26", True), ("2.1", "!=2.1", False)],
)  # fmt: skip
def test_version_in_range(version: str, spec: str, ok: bool) -> None:
    assert install.version_in_range(version, spec) is ok


def _fake_pip(lines: list[str], code: int = 0) -> list[str]:
    body = "; ".join(f"print({ln!r})" for ln in lines)
    return [sys.executable, "-c", f"{body}; raise SystemExit({code})"]


def test_pip_runs_in_order_with_progress_and_stops_at_a_failure() -> None:
    ok = install.PipInstall([_fake_pip(["Collecting torch==1", "Successfully installed torch-1"]),
                             _fake_pip(["Collecting a==1", "Collecting b==2",
                                        "Successfully installed a-1 b-2"])], [0.8, 0.2]).start()  # fmt: skip
    ok.wait()
    assert ok.summary() == (
        True,
        f"installed 3 packages (the tested set, torch {pins.TORCH_VERSION})",
    )
    assert ok.fraction == 1.0
    bad = install.PipInstall([_fake_pip(["ERROR: no matching distribution for torch"], 1),
                              _fake_pip(["Successfully installed x-1"])]).start()  # fmt: skip
    bad.wait()
    okay, line = bad.summary()
    assert not okay and "no matching distribution" in line and "x-1" not in " ".join(bad.lines)
