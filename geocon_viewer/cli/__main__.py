"""``python -m geocon_viewer.cli``: the ``geocon`` command line."""

from . import main

main()
