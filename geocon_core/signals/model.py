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
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from ..files import CLIP_MODEL, ReadRefused, read_text

if TYPE_CHECKING:
    from ..config import SignalsConfig

__all__ = [
    "MODEL_FORMAT",
    "DEFAULT_MODEL",
    "ModelTerm",
    "ClipModel",
    "ClipModelError",
    "ClipModelMismatch",
    "fit_clip_model",
    "load_clip_model",
    "model_path",
    "configured_model",
]

MODEL_FORMAT = "geocon-clip-model/1"
"""The format tag of a clip model file."""
DEFAULT_MODEL = "clip_model.json"
"""The model shipped in this package (beside this module)."""
TERM_FIELDS = ("name", "label", "center", "scale", "weight")
"""The fields of one term of a clip model file (:class:`ModelTerm`), each required."""
RESTORE = (
    "the file was edited or damaged: restore it (for the shipped clip_model.json, reinstall GeoCon), or fit it "
    "again with `geocon validate --fit`"
)
"""What to do about a clip model file that cannot be used, said after what is wrong with it."""


class ClipModelError(ValueError):
    """A clip model file that cannot be used: missing, unreadable, not JSON, of another format, or a
    field of the wrong type or out of range: one sentence, ``problem`` (naming the file and the
    field) and ``advice`` (what to do; :data:`RESTORE` unless told)."""

    def __init__(self, problem: str, advice: str = RESTORE) -> None:
        self.problem, self.advice = problem, advice
        super().__init__(f"{problem}; {advice}" if advice else problem)


class ClipModelMismatch(ClipModelError):
    """The clip model file holds a model of another digest than the configuration pins: ``path``,
    the digest ``found`` in it and the one ``pinned``."""

    def __init__(self, path: Path, found: str, pinned: str) -> None:
        self.path, self.found, self.pinned = path, found, pinned
        super().__init__(
            f"the clip model {path} has digest {found}, but this configuration pins {pinned}",
            "the file was changed since GeoCon was installed; restore it (reinstall GeoCon), or, to ship a model "
            f"fitted anew, set SHIPPED_MODEL_DIGEST in geocon_core/config/stages.py to {found} (docs/validation.md)",
        )


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
    def from_dict(cls, d: Any, where: str = "clip model") -> "ClipModel":
        """The model of a parsed clip model file (``where`` names it); :class:`ClipModelError`
        naming the file and the field for anything of the wrong type or out of range."""
        if not isinstance(d, dict):
            raise ClipModelError(f"{where}: holds a JSON {_kind(d)}, not a clip model (a JSON object)")
        fmt = d.get("format")
        if isinstance(fmt, str) and fmt.startswith("geocon-clip-model/") and fmt != MODEL_FORMAT:
            raise ClipModelError(
                f"{where}: is in the model format {fmt}, and this GeoCon reads {MODEL_FORMAT}",
                "use the GeoCon that fitted it, or fit it again with `geocon validate --fit`",
            )
        if fmt != MODEL_FORMAT:
            raise ClipModelError(f"{where}: not a {MODEL_FORMAT} file (format {fmt!r})")
        for key in ("version", "intercept", "threshold", "terms"):
            if key not in d:
                raise ClipModelError(f"{where}: has no field {key!r}")
        if not isinstance(d["version"], str):
            raise ClipModelError(f"{where}: version is {_shown(d['version'])}, not a string")
        intercept = _number(d["intercept"], where, "intercept")
        threshold = _number(d["threshold"], where, "threshold")
        if not 0.0 < threshold < 1.0:
            raise ClipModelError(f"{where}: threshold is {threshold!r}, outside (0, 1) where clip scores lie")
        fitted = d.get("fitted", {})
        if not isinstance(fitted, dict):
            raise ClipModelError(f"{where}: fitted is {_shown(fitted)}, not a JSON object")
        model = cls(d["version"], float(intercept), _terms(d["terms"], where), float(threshold), dict(fitted))
        return model


def _kind(value: Any) -> str:
    """What a parsed JSON value is, in words."""
    if isinstance(value, bool):
        return "boolean"
    names = {dict: "object", list: "array", str: "string", int: "number", float: "number", type(None): "null"}
    return names.get(type(value), type(value).__name__)


def _shown(value: Any) -> str:
    """A parsed JSON value as a sentence shows it: its text (cut short) and, beside a string, what it is."""
    text = json.dumps(value)
    text = text if len(text) <= 40 else text[:37] + "..."
    return f"{text} (a JSON {_kind(value)})"


def _number(value: Any, where: str, field: str, *, low: float = -math.inf, strict: bool = False) -> float | int:
    """``value`` of the clip model's ``field``: a finite JSON number (never a boolean or a string),
    above ``low`` (``strict``) or at least ``low``; the number as written (so the digest is the
    file's), or :class:`ClipModelError`."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ClipModelError(f"{where}: {field} is {_shown(value)}, not a number")
    if not math.isfinite(value):
        raise ClipModelError(f"{where}: {field} is {value!r}, not a finite number")
    if value < low or (strict and value == low):
        bound = f"above {low:g}" if strict else f"at least {low:g}"
        raise ClipModelError(f"{where}: {field} is {value!r}, and it must be {bound}")
    return value


def _terms(raw: Any, where: str) -> tuple[ModelTerm, ...]:
    """The terms of a clip model file, each checked (:data:`TERM_FIELDS`): a reading GeoCon makes
    (:data:`~.readings.READING_LABELS`) named once, a finite center, a scale above 0 and a weight
    of at least 0 (a larger reading never lowers the score)."""
    from .readings import READING_LABELS

    if not isinstance(raw, list) or not raw:
        what = "an empty array" if raw == [] else _shown(raw)
        raise ClipModelError(f"{where}: terms is {what}, not a list of the readings' terms")
    terms: list[ModelTerm] = []
    for i, t in enumerate(raw):
        at = f"terms[{i}]"
        if not isinstance(t, dict):
            raise ClipModelError(f"{where}: {at} is {_shown(t)}, not a JSON object")
        missing = [k for k in TERM_FIELDS if k not in t]
        extra = [k for k in t if k not in TERM_FIELDS]
        if missing or extra:
            said = f"has no field {missing[0]!r}" if missing else f"has the unknown field {extra[0]!r}"
            raise ClipModelError(f"{where}: {at} {said} (a term has {', '.join(TERM_FIELDS)})")
        name = t["name"]
        if not isinstance(name, str) or name not in READING_LABELS:
            raise ClipModelError(
                f"{where}: {at}.name is {_shown(name)}, not a reading GeoCon makes (one of {', '.join(READING_LABELS)})"
            )
        at = f"{at} ({name!r})"
        if any(u.name == name for u in terms):
            raise ClipModelError(f"{where}: {at} weighs the reading {name!r} a second time")
        if not isinstance(t["label"], str):
            raise ClipModelError(f"{where}: {at} label is {_shown(t['label'])}, not a string")
        center = _number(t["center"], where, f"{at} center")
        scale = _number(t["scale"], where, f"{at} scale", low=0.0, strict=True)
        weight = _number(t["weight"], where, f"{at} weight", low=0.0)
        terms.append(ModelTerm(name, t["label"], center, scale, weight))
    return tuple(terms)


MODEL_DIR = Path(__file__).resolve().parent
"""The folder of the models shipped in the package (:data:`DEFAULT_MODEL` lies in it)."""


def model_path(name: str) -> Path:
    """The file of a model named ``name``: a file of the package (:data:`MODEL_DIR`), a path, or,
    for :data:`DEFAULT_MODEL`, the package's file even when it is missing (so the sentence names it)."""
    here = MODEL_DIR / name
    return here if here.is_file() or name == DEFAULT_MODEL else Path(name)


_LOADED: dict[tuple[Path, int, int], ClipModel] = {}
"""The models read in this process, by file and the file's size and modification time (a file
changed since it was read is read again)."""


def load_clip_model(name: str = DEFAULT_MODEL, digest: str = "") -> ClipModel:
    """The clip model ``name`` (:func:`model_path`), read once per process (:data:`_LOADED`); with ``digest``, it
    must be the model of that digest (a configuration pins its model so): :class:`ClipModelMismatch`
    otherwise. :class:`ClipModelError` (one sentence naming the file) for a file that cannot be used."""
    model = _load(model_path(name))
    if digest and model.digest() != digest:
        raise ClipModelMismatch(model_path(name), model.digest(), digest)
    return model


def configured_model(signals: "SignalsConfig") -> ClipModel | None:
    """The clip model a configuration's ``signals`` decides with (its file, of the digest it pins),
    or None when ``signals`` is off. Every command that scores calls this before any work, so a
    clip model that cannot be used is one sentence (:class:`ClipModelError`) before a clip is read."""
    return load_clip_model(signals.model, signals.model_sha256) if signals.enabled else None


def _load(path: Path) -> ClipModel:
    try:
        stat = path.stat()
    except FileNotFoundError:
        raise ClipModelError(f"the clip model {path} does not exist") from None
    except OSError as exc:
        raise ClipModelError(f"cannot read the clip model {path}: {exc.strerror or exc}") from None
    key = (path, stat.st_size, stat.st_mtime_ns)
    if key not in _LOADED:
        try:
            data = json.loads(read_text(path, CLIP_MODEL, f"the clip model {path}"))  # a regular file within its bound
        except ReadRefused as exc:  # a FIFO or a device (read, it would block or never end), past its bound
            said = f"the clip model {path} is not JSON ({exc.why})" if exc.reason == "encoding" else str(exc)
            raise ClipModelError(said) from None
        except FileNotFoundError:
            raise ClipModelError(f"the clip model {path} does not exist") from None
        except OSError as exc:
            raise ClipModelError(f"cannot read the clip model {path}: {exc.strerror or exc}") from None
        except (ValueError, RecursionError) as exc:  # not UTF-8, not JSON, nested past the parser
            said = exc.msg if isinstance(exc, json.JSONDecodeError) else type(exc).__name__
            raise ClipModelError(f"the clip model {path} is not JSON ({said})") from None
        _LOADED[key] = ClipModel.from_dict(data, str(path))
    return _LOADED[key]


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
