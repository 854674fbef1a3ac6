"""``python -m sb3_crowdnav.cli``: the ``sb3-crowdnav`` command."""

import sys

from sb3_crowdnav.cli import main

sys.exit(main())
