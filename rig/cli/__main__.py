"""`python -m rig.cli` runs the `rig` command (same as the console script)."""

import sys

from rig.cli import main

sys.exit(main())
