"""``python -m rs_localizer.evaluation.experiments``."""

import sys

from . import main

sys.exit(main())
