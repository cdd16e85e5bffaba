"""``python -m prosplat.worker JOB.json | --serve``: the worker's entry point."""

from __future__ import annotations

import sys

from prosplat.worker.jobs import run_job_file
from prosplat.worker.protocol import EXIT_USAGE
from prosplat.worker.serve import serve

USAGE = """\
Blender's own Python usually has no torch. The add-on therefore describes every job as plain
data (numbers, paths, numpy arrays) and hands it to an external interpreter: JOB.json is
{"task": NAME, "params": {...}}; JOB.status.json tells its state, progress and result;
creating JOB.cancel stops it. --serve runs jobs named on stdin, one JSON line each, keeping
the models loaded between them.

usage: python -m prosplat.worker JOB.json | --serve"""


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv == ["--serve"]:
        return serve()
    if len(argv) != 1 or argv[0] in ("-h", "--help"):
        print(USAGE, file=sys.stderr)
        return EXIT_USAGE
    return run_job_file(argv[0])
