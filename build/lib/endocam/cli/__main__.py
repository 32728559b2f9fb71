"""``python -m endocam.cli``: the same as the ``endocam`` command."""

import sys

from endocam.cli import main

sys.exit(main())
