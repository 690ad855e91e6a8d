"""``python -m piezopreload.cli``."""

import sys

from piezopreload.cli import main

sys.exit(main())
