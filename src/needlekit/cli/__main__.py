"""``python -m needlekit.cli``."""

import sys

from needlekit.cli import main

sys.exit(main())
