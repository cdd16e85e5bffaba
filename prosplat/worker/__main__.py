"""``python -m prosplat.worker JOB.json``: see :mod:`prosplat.worker`."""

import sys

from prosplat.worker import main

sys.exit(main())
