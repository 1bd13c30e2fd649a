"""GeoCon viewers: adapters that draw the core's audit records in Rerun and Viser.

Viewers consume :mod:`geocon_core` records and never compute scores themselves; nothing in
:mod:`geocon_core` imports this package.
"""

from geocon_core import __version__

__all__ = ["__version__"]
