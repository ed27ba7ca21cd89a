"""``python -m cdf_mj.cli``: the same as ``python -m cdf_mj`` and the ``cdf-mj`` script."""

import sys

from cdf_mj.cli import main

sys.exit(main())
