"""One clip-level finding: the verdict a person reads first, its reason, and ``clip_score``.

``clip_score`` runs from 0 (sound) to 1 (broken); it is the number the validation's AUCs are
computed on. It is a smooth, monotone reading of the report gate's headroom
(:func:`report_margin`, negative when the background fails; :mod:`geocon_core.scoring.verdict` re-exports it):
``1 / (1 + exp(CLIP_SCORE_SLOPE * margin))``, so 0.5 sits exactly on the gate, a clip that fails
reads above 0.5 and one that passes below it, and the order of clips is the order of their
headroom. A clip that cannot be judged has no score (None) and the verdict ``cannot judge`` with
the reason the background gave.

The slope only spreads the scores; it moves no verdict and no ranking.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

from ..signals import ClipModel

__all__ = [
    "CLIP_SCORE_SLOPE",
    "VERDICT_WORDS",
    "ClipFinding",
    "clip_score",
    "clip_finding",
    "model_finding",
    "report_margin",
]

CLIP_SCORE_SLOPE = 4.0
"""The slope of the logistic ``clip_score`` over the report margin (:func:`clip_score`)."""
DRIFT_MARGIN = 0.25
"""The headroom a clip failed by the multi-view check reads at most (minus this): its clip score
is then above 0.73 whatever its pair fits' headroom."""
VERDICT_WORDS = ("consistent", "inconsistent", "cannot judge")
"""The clip-level verdicts a :class:`ClipFinding` can read."""


@dataclass(frozen=True)
class ClipFinding:
    """``verdict`` (one of :data:`VERDICT_WORDS`), ``reason`` (one sentence, what decided it) and
    ``clip_score`` (0 sound .. 1 broken; None when the clip cannot be judged)."""

    verdict: str
    reason: str
    clip_score: float | None
    parts: tuple[tuple[str, float], ...] = ()
    """Where a clip model made the score: each weighed reading's contribution to its log-odds
    (name, value), largest first ("why this score"); empty for the background's own score."""

    def to_dict(self) -> dict[str, object]:
        return {"verdict": self.verdict, "reason": self.reason}


def report_margin(ir: float | None, ge: float | None, ir_gate: float, ge_gate: float) -> float | None:
    """Headroom to the report gate as a fraction of each gate's range, the smaller of
    ``(ir - ir_gate) / (1 - ir_gate)`` and ``(ge_gate - ge) / ge_gate``: negative exactly when the
    clip fails the report gate, None when it cannot be judged."""
    if ir is None or ge is None:
        return None
    ir_room = (ir - ir_gate) / (1.0 - ir_gate) if ir_gate < 1.0 else ir - ir_gate
    return float(min(ir_room, (ge_gate - ge) / ge_gate if ge_gate > 0 else ge_gate - ge))


def clip_score(margin: float | None) -> float | None:
    """The clip score of a report-gate headroom (None stays None)."""
    if margin is None or not math.isfinite(margin):
        return None
    return 1.0 / (1.0 + math.exp(max(-50.0, min(50.0, CLIP_SCORE_SLOPE * margin))))


def clip_finding(
    *,
    model: str,
    ir: float | None,
    ge: float | None,
    consistent: bool | None,
    margin: float | None,
    ir_gate: float,
    ge_gate: float,
    note: str,
    shots: int = 0,
    drift: str | None = None,
) -> ClipFinding:
    """The finding of a background verdict (``consistent`` True / False / None) with its IR, GE,
    the report gates, the headroom ``margin`` and the background's own ``note`` (why the model was
    chosen, or why it could not be judged). ``shots``: the number of shots of a clip with cuts
    (the background is then that of the shot that decides). ``drift``: what the multi-view check
    found when it failed the background (:mod:`geocon_core.reconstruction.multiview`), whose pair fits pass."""
    where = f" (the shot that decides, of {shots})" if shots > 1 else ""
    if consistent is None or ir is None or ge is None:
        return ClipFinding("cannot judge", note or "the background could not be judged", None)
    values = f"IR {ir:.3f}, GE {ge:.2f} px"
    if consistent:
        return ClipFinding(
            "consistent",
            f"the background{where} fits one {model} model: {values} (needs IR >= {ir_gate:g}, GE <= {ge_gate:g} px)",
            clip_score(margin),
        )
    fails = []
    if drift is not None and ir >= ir_gate and ge <= ge_gate:
        return ClipFinding(
            "inconsistent",
            f"the background fits its {model} model pair by pair ({values}), but {drift}",
            clip_score(margin if margin is None else min(margin, -DRIFT_MARGIN)),
        )
    if ir < ir_gate:
        fails.append(f"only {ir:.1%} of its matches fit (needs {ir_gate:.0%})")
    if ge > ge_gate:
        fails.append(f"its median residual is {ge:.2f} px (needs <= {ge_gate:g} px)")
    return ClipFinding(
        "inconsistent",
        f"the background{where} breaks its {model} model: " + " and ".join(fails or [values]),
        clip_score(margin),
    )


def model_finding(
    background: ClipFinding,
    values: Mapping[str, float | None],
    model: ClipModel,
    decisive_shortfall: float = math.inf,
    drift: str | None = None,
) -> ClipFinding:
    """The finding of a clip model (:mod:`geocon_core.signals.model`) over the readings ``values``:
    ``inconsistent`` when the model's score reaches its threshold, else ``consistent``, the reason
    naming the readings that pushed the score up most. A background that fails its report gate by
    more than ``decisive_shortfall`` (the reading ``shortfall``) fails the clip whatever the model
    says, and the clip score is then the background's own (above any the model gives); so does a
    drifting layer (``drift``: what the multi-view check found, when it counts) beside a background
    that fails its gate at all (``shortfall`` above 0). A clip whose
    background cannot be judged (``background.verdict == "cannot judge"``) is judged on its other
    readings; it stays ``cannot judge`` only when the model weighs none of them (no reading beyond
    the background's could be made)."""
    weighed = {t.name for t in model.terms if t.weight > 0}  # a reading at weight 0 explains nothing
    if background.verdict == "cannot judge" and all(values.get(n) is None for n in weighed - {"shortfall"}):
        return background
    score = model.score(values)
    parts = tuple(
        sorted(((k, v) for k, v in model.contributions(values).items() if k in weighed), key=lambda kv: -kv[1])
    )
    shortfall = values.get("shortfall")
    head = None
    if shortfall is not None and shortfall > decisive_shortfall:
        head = f"the background fails decisively ({shortfall:.1f} gate ranges short, beyond {decisive_shortfall:g})"
    elif drift is not None and shortfall is not None and shortfall > 0:
        head = f"a layer drifts against the camera path ({drift}) and the background fails its gate"
    if head is not None:
        return ClipFinding(
            "inconsistent", f"{head}; {background.reason}", max(score, background.clip_score or score), parts
        )
    labels = {t.name: t.label for t in model.terms}
    up = [f"{labels[name]} {value:+.2f}" for name, value in parts if value > 0.005][:3]
    why = f"; it rises with {', '.join(up)}" if up else ""
    if score >= model.threshold:
        verdict, head = "inconsistent", f"clip score {score:.2f} reaches the model's {model.threshold:.2f}"
    else:
        verdict, head = "consistent", f"clip score {score:.2f} stays under the model's {model.threshold:.2f}"
    return ClipFinding(verdict, f"{head}{why}; {background.reason}", score, parts)
