"""GeoCon core: ground-truth-free scoring of geometric consistency in video.

The package imports nothing heavy at import time; import the stage modules you need:

- :mod:`geocon_core.geometry`: pure two-view geometry (homographies, Sampson distance, poses);
- :mod:`geocon_core.verdict`: the verdict rules (translation gate H / F / U, report gate, flags);
- :mod:`geocon_core.synth`: synthetic scenes with exact ground truth (``geocon synth``);
- :mod:`geocon_core.bench`, :mod:`geocon_core.tables`, :mod:`geocon_core.stats`,
  :mod:`geocon_core.report`: benchmarks of many clips (``geocon bench``, ``geocon report``).
"""

from ._version import __version__

__all__ = ["__version__"]
