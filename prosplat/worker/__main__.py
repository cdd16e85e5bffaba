"""``python -m prosplat.worker JOB.json``: see :mod:`prosplat.worker`."""

import sys

from prosplat.worker.cli import main

sys.exit(main())
