"""Build the installable Blender extension zip: ``python scripts/build_addon.py [--out dist]``.

The zip holds the add-on (``addon/``) at its root and a pure-Python wheel of ``prosplat``
(listed under ``wheels`` in the manifest, so Blender installs it with the extension); torch and
the other requirements are not bundled (gigabytes, per platform): the add-on's preferences
install them or point at an external Python. Everything is written with ``zipfile`` in a fixed
order with fixed timestamps, so the same sources give the same bytes. The manifest is checked
here (required keys, id, version, tagline, permissions) and, when the ``bpy`` module is
installed, by Blender's own ``blender_ext.py validate`` on the finished zip.
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import importlib.util
import io
import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
ADDON = ROOT / "addon"
PACKAGE = ROOT / "prosplat"
DATE = (2024, 1, 1, 0, 0, 0)  # fixed zip timestamps: reproducible builds
REQUIRED = ("schema_version", "id", "version", "name", "tagline", "maintainer", "type",
            "blender_version_min", "license")  # fmt: skip
PACKAGE_DATA = ("*.py", "render/*.cpp", "render/*.h", "weights/*.safetensors")


def check_manifest(manifest: dict) -> None:
    """Raise ValueError naming the first problem Blender would refuse the manifest for."""
    missing = [k for k in REQUIRED if k not in manifest]
    if missing:
        raise ValueError(f"blender_manifest.toml lacks {missing}")
    if manifest["schema_version"] != "1.0.0" or manifest["type"] != "add-on":
        raise ValueError("manifest must have schema_version 1.0.0 and type 'add-on'")
    if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", manifest["id"]):
        raise ValueError(f"manifest id {manifest['id']!r} must be a Python identifier")
    if not re.fullmatch(r"\d+\.\d+\.\d+", manifest["version"]):
        raise ValueError(f"manifest version {manifest['version']!r} must be semantic (1.2.3)")
    tag = manifest["tagline"]
    if len(tag) > 64 or tag[-1] in ".!?":
        raise ValueError("tagline must be at most 64 characters, without final punctuation")
    major, minor, _ = (int(x) for x in manifest["blender_version_min"].split("."))
    if (major, minor) < (4, 2):
        raise ValueError("blender_version_min must be 4.2.0 or later (extensions need 4.2)")
    for key, reason in manifest.get("permissions", {}).items():
        if len(reason) > 64 or reason.endswith("."):
            raise ValueError(f"permission {key!r}: reason must be <= 64 chars, no final period")
    if not all(lic.startswith("SPDX:") for lic in manifest["license"]):
        raise ValueError("licenses must be SPDX identifiers like 'SPDX:MIT'")


def _files(base: Path, patterns) -> list[Path]:
    found = {p for pat in patterns for p in base.rglob(pat) if "__pycache__" not in p.parts}
    return sorted(found)


def _zinfo(name: str) -> zipfile.ZipInfo:
    info = zipfile.ZipInfo(name, DATE)
    info.compress_type = zipfile.ZIP_DEFLATED
    info.external_attr = 0o644 << 16
    return info


def build_wheel(version: str) -> tuple[str, bytes]:
    """A py3-none-any wheel of the ``prosplat`` package (no dependencies declared: Blender
    installs extension wheels as they are, and torch must not be pulled in by accident)."""
    dist = f"prosplat-{version}.dist-info"
    files = {f"prosplat/{p.relative_to(PACKAGE).as_posix()}": p.read_bytes()
             for p in _files(PACKAGE, PACKAGE_DATA)}  # fmt: skip
    files[f"{dist}/METADATA"] = (
        f"Metadata-Version: 2.1\nName: prosplat\nVersion: {version}\n"
        "Summary: Feed-forward 3D Gaussian splatting with one-step enhancement\n"
    ).encode()
    files[f"{dist}/WHEEL"] = (
        b"Wheel-Version: 1.0\nGenerator: prosplat build_addon\nRoot-Is-Purelib: true\n"
        b"Tag: py3-none-any\n"
    )
    files[f"{dist}/top_level.txt"] = b"prosplat\n"
    record = []
    for name, data in files.items():
        digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
        record.append(f"{name},sha256={digest},{len(data)}")
    files[f"{dist}/RECORD"] = ("\n".join([*record, f"{dist}/RECORD,,"]) + "\n").encode()
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in files.items():
            zf.writestr(_zinfo(name), data)
    return f"prosplat-{version}-py3-none-any.whl", buf.getvalue()


def manifest_with_wheels(text: str, wheels: list[str]) -> str:
    """The manifest text with a top-level ``wheels`` list (before the first table)."""
    line = "wheels = [" + ", ".join(f'"./wheels/{w}"' for w in wheels) + "]\n"
    first_table = re.search(r"^\[", text, flags=re.M)
    at = first_table.start() if first_table else len(text)
    return text[:at] + line + "\n" + text[at:]


def build(out_dir: Path) -> Path:
    text = (ADDON / "blender_manifest.toml").read_text()
    manifest = tomllib.loads(text)
    check_manifest(manifest)
    wheel_name, wheel = build_wheel(manifest["version"])
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / f"{manifest['id']}-{manifest['version']}.zip"
    tmp = target.with_name(f".{target.name}.tmp")
    with zipfile.ZipFile(tmp, "w") as zf:
        zf.writestr(_zinfo("blender_manifest.toml"), manifest_with_wheels(text, [wheel_name]))
        for path in _files(ADDON, ("*.py", "*.md")):
            zf.writestr(_zinfo(path.relative_to(ADDON).as_posix()), path.read_bytes())
        zf.writestr(_zinfo(f"wheels/{wheel_name}"), wheel)
    os.replace(tmp, target)
    return target


def blender_validate(zip_path: Path) -> str | None:
    """Run Blender's own validator from the installed ``bpy`` module; None if not available,
    else its output. Raises RuntimeError if it rejects the package."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        return None
    base = Path(list(spec.submodule_search_locations)[0])
    tools = sorted(base.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not tools:
        return None
    res = subprocess.run([sys.executable, str(tools[-1]), "validate", str(zip_path)],
                         capture_output=True, text=True)  # fmt: skip
    if res.returncode != 0 or "error" in res.stdout.lower():
        raise RuntimeError(f"Blender rejects {zip_path}: {res.stdout}{res.stderr}".strip())
    return res.stdout.strip()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "dist", help="output folder (dist/)")
    args = ap.parse_args(argv)
    try:
        zip_path = build(args.out)
        checked = blender_validate(zip_path)
    except (ValueError, RuntimeError, OSError) as e:
        print(f"build_addon: {e}", file=sys.stderr)
        return 1
    size = zip_path.stat().st_size / 2**20
    print(f"{zip_path} ({size:.1f} MiB)")
    print(
        f"Blender validate: {checked}"
        if checked is not None
        else "Blender validate: skipped (no bpy)"
    )
    print("Install: Blender > Edit > Preferences > Get Extensions > Install from Disk")
    return 0


if __name__ == "__main__":
    sys.exit(main())
