"""``python -m skintopo.cli``."""

import sys

from skintopo.cli import main

sys.exit(main())
