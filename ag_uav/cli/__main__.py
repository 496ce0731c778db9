"""``python -m ag_uav.cli``: the ``ag-uav`` command."""

import sys

from . import main

sys.exit(main())
