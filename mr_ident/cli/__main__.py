# SPDX-License-Identifier: Apache-2.0
"""``python -m mr_ident.cli``: the same as the ``mr-ident`` console script."""

import sys

from . import main

sys.exit(main())
