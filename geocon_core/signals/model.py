"""One clip score from several readings: a small, monotone logistic model.

Each reading (a number where larger means more broken) enters as a term ``weight * (value -
center) / scale`` with ``weight >= 0``, so a larger reading never lowers the score; a missing
reading contributes nothing. The clip score is ``1 / (1 + exp(-(intercept + sum of terms)))``,
and the terms are its explanation: every clip's score is the sum of its readings' contributions,
shown reading by reading ("why this score").

A model is fitted on the tune half of the annotated clips (``geocon validate --fit``): clips with a
geometric artifact against clean-looking generated clips and real-camera clips, classes weighted
equally, an L2 penalty on the weights, by Newton steps with the weights held non-negative. The
verdict's threshold is then the score above which at most ``real_false_flags`` of the tune half's
real-camera clips lie. The model is a versioned JSON file (:data:`MODEL_FORMAT`); the shipped one is
:data:`DEFAULT_MODEL`, and its digest is part of the configuration hash.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

__all__ = ["MODEL_FORMAT", "DEFAULT_MODEL", "ModelTerm", "ClipModel", "fit_clip_model", "load_clip_model", "model_path"]

MODEL_FORMAT = "geocon-clip-model/1"
"""The format tag of a clip model file."""
DEFAULT_MODEL = "clip_model.json"
"""The model shipped in this package (beside this module)."""


@dataclass(frozen=True)
class ModelTerm:
    """One reading's term: ``weight * (value - center) / scale``; ``label`` names it for people."""

    name: str
    label: str
    center: float
    scale: float
    weight: float

    def contribution(self, value: float | None) -> float:
        if value is None or not math.isfinite(value):
            return 0.0
        return self.weight * (value - self.center) / self.scale


@dataclass(frozen=True)
class ClipModel:
    """A fitted clip model (module docstring). ``threshold``: the clip score at and above which a
    clip is called inconsistent. ``fitted``: what it was fitted on (counts, the annotation file's
    digest, the penalty), for the record of where the numbers came from."""

    version: str
    intercept: float
    terms: tuple[ModelTerm, ...]
    threshold: float
    fitted: dict[str, Any] = field(default_factory=dict)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.terms)

    def contributions(self, values: Mapping[str, float | None]) -> dict[str, float]:
        """Each term's contribution to the log-odds for the readings ``values`` (by name)."""
        return {t.name: t.contribution(values.get(t.name)) for t in self.terms}

    def score(self, values: Mapping[str, float | None]) -> float:
        """The clip score (0 sound .. 1 broken) of the readings ``values``."""
        z = self.intercept + sum(self.contributions(values).values())
        return 1.0 / (1.0 + math.exp(-max(-50.0, min(50.0, z))))

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": MODEL_FORMAT,
            "version": self.version,
            "intercept": self.intercept,
            "threshold": self.threshold,
            "terms": [asdict(t) for t in self.terms],
            "fitted": self.fitted,
        }

    def digest(self) -> str:
        """First 12 hex digits of the SHA-256 of the model's canonical JSON (computed once per model)."""
        return self._digest

    @cached_property
    def _digest(self) -> str:
        blob = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(blob.encode()).hexdigest()[:12]

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "clip model") -> "ClipModel":
        if d.get("format") != MODEL_FORMAT:
            raise ValueError(f"{where}: not a {MODEL_FORMAT} file (format {d.get('format')!r})")
        try:
            terms = tuple(ModelTerm(**t) for t in d["terms"])
            model = cls(
                str(d["version"]), float(d["intercept"]), terms, float(d["threshold"]), dict(d.get("fitted", {}))
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{where}: malformed ({exc})") from None
        for t in terms:
            if not (t.scale > 0 and t.weight >= 0 and math.isfinite(t.center)):
                raise ValueError(f"{where}: term {t.name!r} needs scale > 0, weight >= 0 and a finite center")
        if not 0.0 < model.threshold < 1.0:
            raise ValueError(f"{where}: threshold must lie in (0, 1), got {model.threshold}")
        return model


def model_path(name: str) -> Path:
    """The file of a model named ``name``: a file of this package (``clip_model.json``) or a path."""
    here = Path(__file__).resolve().parent / name
    return here if here.is_file() else Path(name)


_LOADED: dict[Path, ClipModel] = {}


def load_clip_model(name: str = DEFAULT_MODEL, digest: str = "") -> ClipModel:
    """The clip model ``name`` (:func:`model_path`), read once per process; with ``digest``, it
    must be the model of that digest (a configuration pins its model so)."""
    model = _load(model_path(name))
    if digest and model.digest() != digest:
        raise ValueError(
            f"the clip model {model_path(name)} has digest {model.digest()}, but the configuration pins {digest} "
            "(fitted anew? set signals.model_sha256 to its digest)"
        )
    return model


def _load(path: Path) -> ClipModel:
    if path not in _LOADED:
        try:
            data = json.loads(path.read_text())
        except OSError as exc:
            raise ValueError(f"cannot read the clip model {path}: {exc.strerror or exc}") from None
        except ValueError as exc:
            raise ValueError(f"the clip model {path} is not JSON: {exc}") from None
        _LOADED[path] = ClipModel.from_dict(data, str(path))
    return _LOADED[path]


def _newton(X: np.ndarray, y: np.ndarray, w: np.ndarray, l2: float, iters: int = 100) -> np.ndarray:
    """Weighted logistic regression with an L2 penalty on all but the intercept and the weights
    held non-negative (projected Newton steps); returns [intercept, weights...]."""
    Xb = np.c_[np.ones(len(X)), X]
    b = np.zeros(Xb.shape[1])
    pen = np.r_[0.0, np.full(X.shape[1], l2)]
    for _ in range(iters):
        p = 1.0 / (1.0 + np.exp(-np.clip(Xb @ b, -50, 50)))
        grad = Xb.T @ (w * (p - y)) + pen * b
        hess = (Xb * (w * p * (1 - p))[:, None]).T @ Xb + np.diag(pen + 1e-9)
        free = np.r_[True, (b[1:] > 0) | (grad[1:] < 0)]  # a weight held at 0 by the bound stays out
        step = np.zeros_like(b)
        step[free] = np.linalg.solve(hess[np.ix_(free, free)], grad[free])
        new = b - step
        new[1:] = np.maximum(new[1:], 0.0)
        if np.max(np.abs(new - b)) < 1e-10:
            b = new
            break
        b = new
    return b


def fit_clip_model(
    readings: Sequence[Mapping[str, float | None]],
    broken: Sequence[bool],
    groups: Sequence[str],
    spared: Sequence[bool],
    terms: Sequence[tuple[str, str]],
    *,
    l2: float = 1.0,
    real_false_flags: float = 0.05,
    version: str,
    fitted: Mapping[str, Any] | None = None,
) -> ClipModel:
    """Fit a :class:`ClipModel` on clips with ``readings`` (by name) and ``broken`` (True: the score
    should be high). ``groups`` names each clip's kind (clips with an artifact, planted failures,
    clean-looking generated clips, real-camera clips, ...): the broken and the sound clips weigh the
    same in all, and within each, every group weighs the same whatever its size. ``terms``: (name,
    label) of the readings used; a missing reading sits at its center. The threshold leaves at most
    ``real_false_flags`` of the ``spared`` clips (the real-camera clips) at or above it."""
    n = len(readings)
    if not (n == len(broken) == len(groups) == len(spared)):
        raise ValueError("readings, broken, groups and spared must have one entry per clip")
    y = np.asarray(broken, float)
    if y.sum() == 0 or (1 - y).sum() == 0:
        raise ValueError("fitting a clip model needs broken and sound clips")
    raw = np.array([[np.nan if (v := r.get(name)) is None else float(v) for name, _ in terms] for r in readings], float)
    centers, scales = [], []
    for j in range(raw.shape[1]):
        col = raw[:, j][np.isfinite(raw[:, j])]
        if not len(col):
            raise ValueError(f"no clip has the reading {terms[j][0]!r}")
        lo, mid, hi = np.percentile(col, [10, 50, 90])
        centers.append(float(mid))
        scales.append(float(hi - lo) if hi > lo else 1.0)
    X = (np.where(np.isfinite(raw), raw, np.array(centers)) - np.array(centers)) / np.array(scales)
    w = np.ones(n)
    kinds = np.asarray(groups, object)
    for side in (y == 1, y == 0):
        names = sorted(set(kinds[side]))
        for name in names:
            member = side & (kinds == name)
            w[member] = 1.0 / (len(names) * member.sum())
    b = _newton(X, y, w / w.mean(), l2)
    model_terms = tuple(
        ModelTerm(name, label, c, s, float(wt))
        for (name, label), c, s, wt in zip(terms, centers, scales, b[1:], strict=True)
    )
    draft = ClipModel(version, float(b[0]), model_terms, 0.5, dict(fitted or {}))
    scores = np.array([draft.score(r) for r, keep in zip(readings, spared, strict=True) if keep])
    threshold = 0.5
    if len(scores):
        # the smallest threshold that leaves at most the allowed share of those clips at or above it
        ranked = np.sort(scores)[::-1]
        allowed = int(math.floor(real_false_flags * len(ranked)))
        threshold = float(np.nextafter(ranked[min(allowed, len(ranked) - 1)], 1.0))
    threshold = min(max(threshold, 1e-6), 1 - 1e-6)
    counts = {str(g): int(np.sum(kinds == g)) for g in sorted(set(kinds))}
    info = {**draft.fitted, "clips": counts, "l2": l2, "real_false_flags": real_false_flags}
    return ClipModel(version, draft.intercept, model_terms, threshold, info)
