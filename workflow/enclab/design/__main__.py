"""``python -m enclab.design``: see :mod:`enclab.design.cli`."""
import sys

from enclab.design.cli import main

sys.exit(main())
