"""A reward for training video generators: clips scored in memory, preference pairs per prompt.

A training loop holds its samples as arrays; :class:`RewardScorer` scores them where they are
(numpy or torch, CPU or GPU memory, one clip or a batch), writes nothing, and returns a
:class:`RewardResult` per clip: a score where higher is more consistent, its interval, whether it
can judge and why not, and the readings behind it. The score reads short windows of fresh
tracks against the background's models (:mod:`.windows`). Guards (:mod:`.guards`) make frozen, nearly
static, repeated, blurred, textureless and cut clips "cannot judge", so doing nothing never wins.
:func:`write_pairs` (``geocon pairs``) ranks the clips of each prompt of a manifest and writes
chosen/rejected pairs whose margin clears the noise.

>>> from geocon_core.reward import sample_evenly
>>> sample_evenly(48, 4).tolist()
[0, 16, 31, 47]
"""

from .api import REWARD_PRESET, RewardScorer, sample_evenly, score_reward
from .guards import GUARD_NAMES, GuardReading, read_guards
from .pairs import (
    ManifestError,
    ManifestRow,
    PairsSummary,
    decode_clip,
    margin_interval,
    read_manifest,
    reward_hash,
    write_pairs,
)
from .result import RewardResult, bootstrap_mean, pair_values, reward_of_record
from .windows import canvas_greys, window_values

__all__ = [
    "REWARD_PRESET",
    "GUARD_NAMES",
    "GuardReading",
    "ManifestError",
    "ManifestRow",
    "PairsSummary",
    "RewardResult",
    "RewardScorer",
    "bootstrap_mean",
    "decode_clip",
    "margin_interval",
    "pair_values",
    "read_guards",
    "read_manifest",
    "reward_of_record",
    "reward_hash",
    "window_values",
    "canvas_greys",
    "sample_evenly",
    "score_reward",
    "write_pairs",
]
