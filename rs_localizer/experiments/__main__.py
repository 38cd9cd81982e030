"""``python -m rs_localizer.experiments``."""

import sys

from . import main

sys.exit(main())
