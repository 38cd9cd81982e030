"""``python -m rs_localizer`` = the ``rs-localizer`` command."""

import sys

from .cli import main

sys.exit(main())
