"""``python -m enclab``: the ``enclab`` command (:func:`enclab.cli.main`)."""
import sys

from enclab.cli import main

sys.exit(main())
