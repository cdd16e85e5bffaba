"""Install ``prosplat``'s requirements into a folder of the add-on with Blender's own pip.

pip runs as a subprocess (``sys.executable -m pip install --target DIR ...``) whose output a
thread reads line by line, so the preferences can show progress ("Collecting torch",
"Installing ...") while Blender stays responsive, and the result is one clear line: what was
installed, or the error pip gave.
"""

from __future__ import annotations

import re
import subprocess
import sys
import threading
from collections.abc import Sequence

from . import runtime

_EXPECTED_PACKAGES = 25  # rough number of "Collecting" lines a fresh install prints


def pip_command(target: str, packages: Sequence[str], extra_args: str = "") -> list[str]:
    return [sys.executable, "-m", "pip", "install", "--upgrade", "--target", target,
            "--disable-pip-version-check", *extra_args.split(), *packages]  # fmt: skip


class PipInstall:
    """One pip run; :meth:`poll` gives (finished, fraction, last line)."""

    def __init__(self, command: list[str]) -> None:
        self.command = command
        self.lines: list[str] = []
        self.fraction, self.returncode = 0.0, None
        self._collected = 0

    def start(self) -> PipInstall:
        try:
            self.proc = subprocess.Popen(
                self.command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1
            )
        except OSError as e:
            self.lines.append(f"could not start pip: {e}")
            self.returncode = -1
            return self
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()
        return self

    def _read(self) -> None:
        for line in self.proc.stdout:
            line = line.rstrip()
            if not line:
                continue
            self.lines.append(line)
            if line.startswith("Collecting "):
                self._collected += 1
                self.fraction = max(
                    self.fraction, 0.7 * min(1.0, self._collected / _EXPECTED_PACKAGES)
                )
            elif line.startswith("Installing collected packages"):
                self.fraction = max(self.fraction, 0.8)
            elif line.startswith("Successfully installed"):
                self.fraction = 1.0
        self.returncode = self.proc.wait()

    def poll(self) -> bool:
        return self.returncode is not None

    def wait(self) -> None:
        if hasattr(self, "_thread"):
            self._thread.join()

    @property
    def last_line(self) -> str:
        return self.lines[-1] if self.lines else "starting pip"

    def cancel(self) -> None:
        if self.returncode is None and hasattr(self, "proc"):
            self.proc.terminate()

    def summary(self) -> tuple[bool, str]:
        """(ok, one line for the user)."""
        if self.returncode == 0:
            done = next((ln for ln in reversed(self.lines) if ln.startswith("Successfully")), "")
            return True, done or "requirements are already installed"
        errors = [ln for ln in self.lines if re.match(r"(ERROR|error)\b", ln)]
        tail = errors[-1] if errors else (self.lines[-1] if self.lines else "no output")
        if "No module named pip" in "\n".join(self.lines):
            tail += " (this Python has no pip; run `python -m ensurepip` with Blender's Python)"
        return False, f"pip failed (exit code {self.returncode}): {tail}"


#: The install running now (one at a time), for the preferences to draw.
CURRENT: dict[str, PipInstall] = {}


def start_install(extra_args: str = "", command: list[str] | None = None) -> PipInstall:
    cmd = command or pip_command(str(runtime.deps_dir()), runtime.PIP_REQUIREMENTS, extra_args)
    run = PipInstall(cmd).start()
    CURRENT["run"] = run
    return run
