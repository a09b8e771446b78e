"""``python -m stillpoint``: the ``stillpoint`` command."""

import sys

from stillpoint import main

sys.exit(main())
