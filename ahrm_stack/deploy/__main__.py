"""``python -m ahrm_stack.deploy``: the deploy command (:func:`ahrm_stack.deploy.cli.main`)."""

import sys

from ahrm_stack.deploy.cli import main

sys.exit(main())
