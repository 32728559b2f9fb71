"""``python -m endocam``: the ``endocam`` command (:func:`endocam.cli.main`)."""

import sys

from endocam.cli import main

if __name__ == "__main__":
    sys.exit(main())
