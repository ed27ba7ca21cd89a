"""``python -m cdf_mj``: the ``cdf-mj`` command without its installed script."""

import sys

from cdf_mj.cli import main

sys.exit(main())
