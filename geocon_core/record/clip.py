"""The audit record of one clip (SPEC section 7): frozen dataclasses, written as

- ``record.json``: everything but the per-match arrays, human-readable and byte-stable;
- ``matches.npz``: per-match coordinates, residuals and inlier masks of every scored pair and
  scale for both families (enough to re-gate at other thresholds without re-running), the
  per-cell AdaDFRC vectors and the first/last point cloud,
  concatenated with offsets, written with fixed zip timestamps so that the same scores give
  the same bytes.

Both read back exactly (:func:`read_record`). The viewers read these records and never
recompute scores.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import os
import zipfile
from dataclasses import asdict, dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

from .._version import __version__
from ..config import ScoreConfig
from ..files import MATCHES, NPZ_ERRORS, RECORD_JSON, ReadRefused, open_regular, read_bytes
from ..media import MAX_FPS, ClipInfo
from ..reconstruction import ARRAY_NAMES as MV_ARRAYS
from ..reconstruction import DenseCloud, MultiViewResult, WindowCloud
from ..regions import REGION_ARRAYS, RegionsPart
from ..signals import MAP_ARRAYS, ClipReadings, load_clip_model
from . import parts as record_parts
from .finding import VERDICT_WORDS, ClipFinding, clip_finding, model_finding, report_margin
from .parts import (
    BackgroundSummary,
    Category,
    CellArrays,
    FamilySummary,
    FitSummary,
    GapSummary,
    GateRecord,
    MatchArrays,
    ObjectEntry,
    ObjectScaleSummary,
    ObjectSummary,
    PairRecord,
    PointCloud,
    PointMaps,
    ScaleSummary,
    ShotRecord,
)
from .parts import Family as Family  # these two re-exported only
from .parts import GateWindow as GateWindow

__all__ = [
    "RECORD_FORMAT",
    *record_parts.__all__,  # every part of a record, re-exported
    "ClipRecord",
    "RecordError",
    "MAX_RECORD_JSON_BYTES",
    "write_record",
    "read_record",
    "read_record_json",
    "read_matches",
    "record_id",
    "RECORD_ID_ARRAY",
    "pinned_model",
    "record_problem",
    "stored_finding",
]

RECORD_FORMAT = "geocon-record/1"
"""The ``format`` field of ``record.json``; a record of another format is refused."""

MAX_RECORD_JSON_BYTES = RECORD_JSON.limit
"""The largest ``record.json`` :func:`read_record_json` parses: 512 MiB. A record holds about
350 bytes per scored (pair, scale), so an hour of 30 fps video under the ``strict`` preset (gaps
1, 4, 8 at three scales) stays below ~350 MB; a larger file is not a record GeoCon wrote, and
is refused before parsing rather than parsed into several GB of memory."""


class RecordError(ValueError):
    """A saved record that cannot be read (missing, unreadable, corrupt, too large, pickled or of
    another format): one sentence naming the file."""


@dataclass(frozen=True, eq=False)
class ClipRecord:
    """Everything GeoCon found about one clip (SPEC section 7); written by :func:`write_record`,
    read back exactly by :func:`read_record`. Compared by identity (it holds arrays).

    clip: the clip's name (file name, or folder name for an image folder).
    video: what the probe pass learnt about the clip (frame count, sizes in px, frame rate in
        frames per second, content box, duplicated frames, hard cuts).
    config: the settings it was scored with; ``config_hash`` their short hash.
    versions: software versions by package name.
    gate: the translation gate (H / F / U), its statistic ``t_inf`` (unit-mean-distance scale),
        margin and the pose estimate it came from.
    background: the background verdict: chosen family, IR (share, 0..1), GE (px of the largest
        scale), the report gate, and both families' per-gap and per-scale summaries.
    pairs: every scored (pair, scale) with both families' fits; ``pairs[i].index`` addresses the
        pair's rows in ``matches``.
    matches: per-match coordinates (px of the pair's scale), residuals (px, or Hartley-normalised
        units for ``f_res``) and inlier masks, concatenated over pairs.
    intrinsics: the 3x3 camera matrix K at the working resolution (px) the gate used, before
        self-calibration (``gate.pose.focal_scale`` scales its focal lengths).
    category: the post-hoc scene family and the rule that fired (None when not decided).
    warnings: one sentence each (e.g. cuts or duplicated frames skipped).
    masks_source: where the object masks came from (``none``, ``builtin`` or an external source).
    masked_share: per frame, the share (0..1) of the content box covered by object masks.
    objects: one summary per tracked object: frames, masked share (0..1), AdaDFRC ``S`` and W2
        (px^2 of the largest scale) and AdaP90 (px^2).
    object_entries: AdaDFRC per object, frame pair and scale (``d_t`` and ``w2`` in px^2 of the
        scale); ``object_entries[i].index`` addresses the entry's rows in ``cells``.
    cells: per-cell AdaDFRC vectors (px) of every object entry, concatenated (None without
        objects).
    cloud: the two-view point cloud of the first/last pair (first-camera coordinates, unit mean
        scene distance), or None.
    dense: the dense clouds (:mod:`geocon_core.reconstruction.dense`) of the first/last pair, then of each
        gate window, when they were asked for (``score_clip(dense=...)``); empty otherwise.
    pointmaps: DUSt3R's point maps of the first/last pair (``--pose dust3r``), or None.
    shots: a clip with hard cuts: each shot judged on its own (the gate is the first shot's and
        ``background`` that of the shot that decides); empty for a clip of one shot.
    dynamic_share: per frame, the share (0..1) of the content the motion segmentation found
        moving incoherently outside the objects (water, fire, smoke, foliage); empty when the
        mask source does not measure it.
    record_id: see the attribute.
    """

    clip: str
    video: ClipInfo
    config: ScoreConfig
    config_hash: str
    versions: dict[str, str]
    gate: GateRecord
    background: BackgroundSummary
    pairs: tuple[PairRecord, ...]
    matches: MatchArrays
    intrinsics: list[list[float]]
    category: Category | None = None
    warnings: tuple[str, ...] = field(default_factory=tuple)
    masks_source: str = "none"
    masked_share: tuple[float, ...] = ()
    objects: tuple[ObjectSummary, ...] = ()
    object_entries: tuple[ObjectEntry, ...] = ()
    cells: CellArrays | None = None
    cloud: PointCloud | None = None
    dense: tuple[WindowCloud, ...] = ()
    pointmaps: PointMaps | None = None
    shots: tuple[ShotRecord, ...] = ()
    dynamic_share: tuple[float, ...] = ()
    multiview: MultiViewResult | None = None
    readings: ClipReadings | None = None
    """The readings beside the background fit (:mod:`geocon_core.signals`), when ``config.signals`` is on."""
    regions: RegionsPart | None = None
    """The region readings over the whole clip and their tracks (:mod:`geocon_core.regions`), when
    ``config.regions`` is on."""
    record_id: str | None = None
    """The id that ties ``record.json`` to its ``matches.npz`` and ``overlays/index.json``
    (:func:`record_id`), as read from ``record.json``; None for a record not yet written, or
    written before records had ids."""
    made_with: ClipFinding | None = field(default=None, compare=False)
    """The finding ``record.json``'s summary holds (the verdict, reason, clip score and "why" it
    was written with), as read; None for a record not read from disk, or whose summary does not
    hold one. It is the finding of a record made with another clip model (:meth:`other_model`)."""

    def finding(self) -> ClipFinding:
        """The clip-level finding: verdict, its reason and ``clip_score`` (:mod:`geocon_core.record.finding`):
        the clip model's (``config.signals``) over :meth:`reading_values` where the record has readings,
        else the background verdict's. Computed once per record (the record is frozen)."""
        return self._finding

    @cached_property
    def _finding(self) -> ClipFinding:
        background = self.background_finding()
        if not self.config.signals.enabled or self.readings is None:
            return background
        if self.other_model() is not None and self.made_with is not None:
            return self.made_with  # its own model is not here: the verdict it was made with
        signals = self.config.signals
        model = load_clip_model(signals.model, signals.model_sha256)
        drift = self.drift_finding() if signals.drift_fails_with_background else None
        return model_finding(background, self.reading_values(), model, signals.decisive_shortfall, drift)

    def other_model(self) -> tuple[str, str] | None:
        """(the digest the record's configuration pins, the digest of the model its
        ``signals.model`` names here) when the record was made with another clip model than that
        one (an earlier release's, a model fitted anew); None when the clip model does not decide
        the record or is the one it pins. :class:`~geocon_core.signals.ClipModelError` for a model
        file that cannot be used."""
        return self._other_model

    @cached_property
    def _other_model(self) -> tuple[str, str] | None:
        signals = self.config.signals
        if not signals.enabled or self.readings is None or not signals.model_sha256:
            return None
        here = load_clip_model(signals.model).digest()
        return None if here == signals.model_sha256 else (signals.model_sha256, here)

    def model_note(self) -> str | None:
        """One sentence when the record was made with another clip model (:meth:`other_model`):
        which one, and that the verdict and clip score shown are those it was made with; else None."""
        other = self.other_model()
        if other is None:
            return None
        pinned, here = other
        return (
            f"made with the clip model {pinned}, not this GeoCon's {here}: the verdict and clip score are those it "
            "was made with; score the clip again to judge it with this model"
        )

    def model_verdict(self) -> str | None:
        """The clip model's verdict where it decides the clip (``config.signals`` on and readings
        recorded), else None (the background verdict decides)."""
        if not self.config.signals.enabled or self.readings is None:
            return None
        return self.finding().verdict

    def reading_values(self) -> dict[str, float | None]:
        """Every reading a clip model can use, by name (:data:`~geocon_core.signals.READING_LABELS`)."""
        bg, cfg = self.background, self.config
        margin = report_margin(bg.ir, bg.ge, cfg.ir_gate, cfg.ge_gate)
        rigidity = [o.adadfrc_w2 for o in self.objects if o.adadfrc_w2 is not None and math.isfinite(o.adadfrc_w2)]
        mv = self.multiview
        return {
            "shortfall": None if margin is None else -margin,
            **(self.readings.values() if self.readings is not None else {}),
            "mv_residual": None if mv is None or mv.mv_ge is None else float(mv.mv_ge),
            "object_rigidity": max(rigidity) if rigidity else None,
        }

    def background_finding(self) -> ClipFinding:
        """The background verdict's finding (:func:`~geocon_core.record.finding.clip_finding`)."""
        bg, cfg = self.background, self.config
        return clip_finding(
            model=bg.model,
            ir=bg.ir,
            ge=bg.ge,
            consistent=bg.consistent,
            margin=report_margin(bg.ir, bg.ge, cfg.ir_gate, cfg.ge_gate),
            ir_gate=cfg.ir_gate,
            ge_gate=cfg.ge_gate,
            note=bg.choice_note,
            shots=len(self.shots),
            drift=self.drift_finding(),
        )

    def drift_finding(self) -> str | None:
        """What the multi-view check found when it fails the background (its largest drifting
        layer), else None (:mod:`geocon_core.reconstruction.multiview`)."""
        mv = self.multiview
        if mv is None or not mv.flagged or not self.config.multiview.enabled:
            return None
        return mv.layers[0].describe()

    def canvas(self) -> dict[str, Any]:
        """The canvas the clip was scored on: source and working size (px), ``scale`` (working px
        per source px, never above 1), whether the clip was ``resized`` once at decode, and the
        background's GE in source px (``ge_source_px``: working px / scale). Pixel gates read
        working px; the source-px figure says what a residual is in the clip's own pixels."""
        v, ge = self.video, self.background.ge
        scale = float(v.scale) if v.scale else 1.0
        return {
            "source_size": list(v.source_size),
            "working_size": list(v.working_size),
            "scale": scale,
            "resized": scale < 1.0,
            "ge_source_px": None if ge is None else float(ge) / scale,
        }

    def canvas_note(self) -> str | None:
        """One sentence when the clip was resized at decode (:meth:`canvas`), else None."""
        c = self.canvas()
        if not c["resized"]:
            return None
        (w, h), (W, H) = c["source_size"], c["working_size"]
        ge_src, ge = c["ge_source_px"], self.background.ge
        said = "" if ge_src is None or ge is None else f"; GE {ge:.2f} px = {ge_src:.2f} source px"
        return (
            f"resized once at decode from {w}x{h} to {W}x{H} (x{c['scale']:.3f}): pixel gates read canvas px, "
            f"1 canvas px = {1 / c['scale']:.2f} source px{said}"
        )

    def summary(self) -> dict[str, Any]:
        """The clip summary printed by ``geocon score --json``."""
        bg, gate = self.background, self.gate
        finding = self.finding()
        return {
            "clip": self.clip,
            "canvas": self.canvas(),
            "verdict": finding.to_dict(),
            "clip_score": finding.clip_score,
            **({"why": dict(finding.parts)} if finding.parts else {}),
            **({"readings": self.reading_values()} if self.readings is not None else {}),
            **({"regions": self.regions.summary()} if self.regions is not None else {}),
            "gate": {
                "label": gate.label,
                "model": gate.model,
                "t_inf": gate.t_inf,
                "pose_present": gate.pose_present,
                "margin": gate.margin,
                "binary_label": gate.binary_label,
                "backend": gate.backend,
            },
            "background": {
                "model": bg.model,
                "ir": bg.ir,
                "ge": bg.ge,
                "valid_pairs": bg.valid_pairs,
                "total_pairs": bg.total_pairs,
                "consistent": bg.consistent,
                "tau_f_px": bg.tau_f_px,
                "other_family": {"model": bg.other.family, "ir": bg.other.ir, "ge": bg.other.ge},
            },
            "per_gap": {
                str(g.gap): {
                    "ir": g.ir,
                    "ge": g.ge,
                    "valid_pairs": g.valid_pairs,
                    "total_pairs": g.total_pairs,
                    "coverage": g.coverage,
                    "judged": g.judged,
                }
                for g in bg.chosen.per_gap
            },
            "coverage": {
                "frames": self.video.num_frames,
                "duplicates": len(self.video.duplicates),
                "cuts": len(self.video.cuts),
                "invalid_reasons": bg.chosen.invalid_reasons,
            },
            "objects": [
                {
                    "id": o.object_id,
                    "frames": o.frames,
                    "adadfrc": o.adadfrc,
                    "adadfrc_w2": o.adadfrc_w2,
                    "adap90": o.adap90,
                    "masked_share": o.masked_share,
                }
                for o in self.objects
            ],
            "masks": self.masks_source,
            **({"dynamic_background": float(np.median(self.dynamic_share))} if self.dynamic_share else {}),
            **({"multiview": self.multiview.summary()} if self.multiview is not None else {}),
            "category": None if self.category is None else self.category.label,
            "preset": self.config.preset,
            "config_hash": self.config_hash,
            "versions": self.versions,
            "warnings": list(self.warnings),
            **(
                {
                    "shots": [
                        {
                            "frames": [s.start, s.end],
                            "gate": s.label,
                            "t_inf": s.t_inf,
                            "model": s.model,
                            "ir": s.ir,
                            "ge": s.ge,
                            "consistent": s.consistent,
                        }
                        for s in self.shots
                    ]
                }
                if self.shots
                else {}
            ),
        }

    def to_json_dict(self) -> dict[str, Any]:
        return {
            "format": RECORD_FORMAT,
            "clip": self.clip,
            "summary": self.summary(),
            "video": self.video.to_dict(),
            "config": self.config.to_dict(),
            "config_hash": self.config_hash,
            "versions": self.versions,
            "intrinsics": self.intrinsics,
            "gate": self.gate.to_json_dict(),
            "background": asdict(self.background),
            "pairs": [asdict(p) for p in self.pairs],
            "category": None if self.category is None else asdict(self.category),
            "warnings": list(self.warnings),
            "masks_source": self.masks_source,
            "masked_share": list(self.masked_share),
            "objects": [asdict(o) for o in self.objects],
            "object_entries": [asdict(e) for e in self.object_entries],
            "cloud": None if self.cloud is None else {"points": int(self.cloud.xyz.shape[0]), "note": self.cloud.note},
            "pointmaps": None if self.pointmaps is None else self.pointmaps.to_json_dict(),
            "dense": [_dense_entry(w) for w in self.dense],
            **({"shots": [asdict(s) for s in self.shots]} if self.shots else {}),
            **({"dynamic_share": list(self.dynamic_share)} if self.dynamic_share else {}),
            **({"multiview": self.multiview.to_json_dict()} if self.multiview is not None else {}),
            **({"readings": self.readings.to_json_dict()} if self.readings is not None else {}),
            **({"regions": self.regions.to_json_dict()} if self.regions is not None else {}),
        }


def _fit_from(d: dict | None) -> FitSummary | None:
    return None if d is None else FitSummary(**d)


def _family_from(d: dict) -> FamilySummary:
    return FamilySummary(
        family=d["family"],
        ir=d["ir"],
        ge=d["ge"],
        valid_pairs=d["valid_pairs"],
        total_pairs=d["total_pairs"],
        per_gap=tuple(GapSummary(**g) for g in d["per_gap"]),
        per_scale=tuple(ScaleSummary(**s) for s in d["per_scale"]),
        invalid_reasons=dict(d["invalid_reasons"]),
        independent_share=float(d.get("independent_share", 0.0)),
    )


def _dumps(obj: Any) -> str:
    return json.dumps(obj, indent=1, sort_keys=False, allow_nan=False) + "\n"


def _arrays(record: ClipRecord) -> dict[str, np.ndarray]:
    """The arrays of ``matches.npz`` (without the record's id), by name, in the order written."""
    arrays = {name: getattr(record.matches, name) for name in MatchArrays.NAMES}
    if record.matches.any_independent:
        arrays.update({name: getattr(record.matches, name) for name in MatchArrays.OPTIONAL})
    if record.cells is not None:
        arrays.update({f"cells_{name}": getattr(record.cells, name) for name in CellArrays.NAMES})
    if record.cloud is not None:
        arrays.update({"cloud_xyz": record.cloud.xyz, "cloud_rgb": record.cloud.rgb})
    if record.pointmaps is not None:
        arrays.update({f"pointmaps_{name}": getattr(record.pointmaps, name) for name in PointMaps.NAMES})
    if record.dense:
        arrays.update(_dense_arrays(record.dense))
    if record.multiview is not None:
        arrays.update(record.multiview.arrays())
    if record.readings is not None:
        arrays.update(record.readings.arrays())
    if record.regions is not None:
        arrays.update(record.regions.arrays())
    return arrays


RECORD_ID_ARRAY = "record_id"
"""The array of ``matches.npz`` that holds the record's id (one unicode string)."""


def record_id(record: ClipRecord) -> str:
    """The id of a record: 16 hex digits of a SHA-256 over its clip (name and fingerprint), its
    configuration hash, its frame count and every array of its ``matches.npz``. The same scores
    give the same id (records stay byte-stable); another record's parts give another.
    :func:`write_record` stores it in ``record.json`` and ``matches.npz``, and the overlays writer
    in ``overlays/index.json``, so that a part copied from another record is refused on reading."""
    h = hashlib.sha256()
    for text in (record.clip, record.video.fingerprint or "", record.config_hash, str(record.video.num_frames)):
        h.update(text.encode("utf-8", "surrogateescape") + b"\0")
    for name, value in _arrays(record).items():
        arr = np.ascontiguousarray(value)
        h.update(f"{name}:{arr.dtype.str}:{arr.shape}".encode() + b"\0")
        h.update(arr.data)
    return h.hexdigest()[:16]


def write_record(record: ClipRecord, out_dir: str | Path) -> Path:
    """Write ``record.json`` and ``matches.npz`` into ``out_dir`` (created), each atomically, both
    holding the record's id (:func:`record_id`)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    rid = record_id(record)
    arrays = {**_arrays(record), RECORD_ID_ARRAY: np.array([rid])}
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, value in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            arr = io.BytesIO()
            np.lib.format.write_array(arr, np.ascontiguousarray(value), allow_pickle=False)
            zf.writestr(info, arr.getvalue())
    doc = record.to_json_dict()
    doc = {"format": doc.pop("format"), "record_id": rid, **doc}
    if record.video.abs_path is not None:  # where the clip lies seen from the record: found again when both move
        doc["video"]["from_record"] = os.path.relpath(record.video.abs_path, os.path.abspath(out.parent))
    for name, data in (("matches.npz", buf.getvalue()), ("record.json", _dumps(doc).encode())):
        tmp = out / f".{name}.part"
        tmp.write_bytes(data)
        tmp.replace(out / name)
    return out / "record.json"


_CORRUPT = "score the clip again"

DENSE_NAMES = ("xyz", "rgb", "pixel", "residual", "kind")
"""The arrays of the dense clouds in ``matches.npz`` (``dense_<name>``, all windows concatenated,
plus ``dense_offsets``: window i holds rows ``offsets[i]:offsets[i + 1]``)."""


def _dense_arrays(dense: tuple[WindowCloud, ...]) -> dict[str, np.ndarray]:
    arrays = {f"dense_{name}": np.concatenate([getattr(w.cloud, name) for w in dense]) for name in DENSE_NAMES}
    arrays["dense_offsets"] = np.cumsum([0, *(len(w.cloud) for w in dense)]).astype(np.int64)
    return arrays


def _nan(v: Any) -> float:
    return float("nan") if v is None else float(v)


def _dense_entry(w: WindowCloud) -> dict[str, Any]:
    T = None if w.T_cam0_camT is None else np.asarray(w.T_cam0_camT, float).tolist()
    tau = None if np.isnan(w.cloud.tau_px) else w.cloud.tau_px
    return {
        "start": w.start,
        "end": w.end,
        "points": len(w.cloud),
        "note": w.cloud.note,
        "tau_px": tau,
        "T_cam0_camT": T,
    }


def _dense_from(entries: list[dict[str, Any]], z: dict[str, np.ndarray]) -> tuple[WindowCloud, ...]:
    if not entries:
        return ()
    if "dense_offsets" not in z:
        raise KeyError("dense_offsets")
    offsets = z["dense_offsets"]
    if offsets.shape != (len(entries) + 1,) or offsets[0] != 0 or np.any(np.diff(offsets) < 0):
        raise ValueError(f"dense_offsets of shape {offsets.shape} do not fit {len(entries)} dense clouds")
    out = []
    for i, e in enumerate(entries):
        rows = slice(int(offsets[i]), int(offsets[i + 1]))
        parts = {name: z[f"dense_{name}"][rows] for name in DENSE_NAMES}
        T = None if e.get("T_cam0_camT") is None else np.asarray(e["T_cam0_camT"], float).reshape(4, 4)
        out.append(
            WindowCloud(
                int(e["start"]),
                int(e["end"]),
                DenseCloud(**parts, note=str(e["note"]), tau_px=_nan(e.get("tau_px"))),
                T,
            )
        )
    return tuple(out)


def read_record_json(path: str | Path) -> tuple[Path, dict[str, Any]]:
    """The folder of a record (given it or its ``record.json``) and its parsed JSON, checked to be
    a GeoCon record. Raises :class:`RecordError` for a file that is missing, unreadable, larger
    than :data:`MAX_RECORD_JSON_BYTES`, not JSON or of another format."""
    p = Path(path)
    folder = p if p.is_dir() else p.parent
    file = folder / "record.json"
    mib = MAX_RECORD_JSON_BYTES // 2**20
    too_large = f"{file} is larger than {mib} MiB, far more than a GeoCon record: refusing to parse it"
    try:
        raw = read_bytes(file, RECORD_JSON)  # a regular file, bounded even when its size is not the real one
    except ReadRefused as exc:
        if exc.reason == "size":
            raise RecordError(too_large) from None
        if exc.reason == "missing" and not file.is_symlink():
            raise RecordError(f"{file} does not exist: give a record folder from `geocon score --out`") from None
        if exc.reason in ("special", "folder"):  # a pipe or a device would block or never end
            raise RecordError(f"{file} is {exc.why}: give a record folder from `geocon score --out`") from None
        raise RecordError(str(exc)) from None
    try:
        d = json.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise RecordError(f"{file} is not a readable GeoCon record (not UTF-8 text): {_CORRUPT}") from None
    except json.JSONDecodeError as exc:
        where = f"line {exc.lineno}, column {exc.colno}"
        raise RecordError(
            f"{file} is not a readable GeoCon record (invalid JSON: {exc.msg.removesuffix(' at')} at {where}): "
            f"{_CORRUPT}"
        ) from None
    except RecursionError:
        raise RecordError(f"{file} is not a readable GeoCon record (JSON nested too deeply): {_CORRUPT}") from None
    fmt = d.get("format") if isinstance(d, dict) else None
    if isinstance(fmt, str) and fmt.startswith("geocon-record/") and fmt != RECORD_FORMAT:
        wrote = d.get("versions", {}).get("geocon") if isinstance(d.get("versions"), dict) else None
        by = f"GeoCon {wrote}" if isinstance(wrote, str) else "another GeoCon version"
        raise RecordError(
            f"{file} was written by {by} in the record format {fmt}, and this GeoCon ({__version__}) reads "
            f"{RECORD_FORMAT}: open it with the GeoCon that wrote it, or score the clip again"
        )
    if fmt != RECORD_FORMAT:
        raise RecordError(f"{file}: not a GeoCon record (format {fmt!r}, expected {RECORD_FORMAT!r})")
    return folder, d


def _npz_refusal(path: Path, exc: BaseException, name: str | None = None) -> RecordError:
    """The sentence for a ``matches.npz`` that numpy could not read without unpickling or at all."""
    if isinstance(exc, ValueError) and "pickle" in str(exc):
        if name is not None:
            return RecordError(f"{path}: {name!r} holds pickled Python objects, which GeoCon never loads")
        with path.open("rb") as f:
            is_pickle = f.read(1) == b"\x80"  # the PROTO opcode that starts a pickle (protocol 2+)
        if not is_pickle:
            return RecordError(f"{path} is not a readable .npz archive (not a zip file): {_CORRUPT}")
        return RecordError(f"{path} is a Python pickle, which GeoCon never loads (unpickling can run code)")
    if isinstance(exc, OSError) and not isinstance(exc, zipfile.BadZipFile):
        return RecordError(f"{path} could not be read ({exc.strerror or exc})")
    return RecordError(f"{path} is not a readable .npz archive ({exc or type(exc).__name__}): {_CORRUPT}")


def read_matches(folder: str | Path, names: Iterable[str], optional: Iterable[str] = ()) -> dict[str, np.ndarray]:
    """The arrays ``names`` of the record's ``matches.npz`` in ``folder``, and those of
    ``optional`` that it holds. Nothing is unpickled (``allow_pickle=False``); a missing, corrupt or
    pickled file, or a missing array, raises :class:`RecordError` naming the file."""
    path = Path(folder) / "matches.npz"
    names, optional = tuple(names), tuple(optional)
    name: str | None = None
    try:
        with open_regular(path, MATCHES) as fh:  # a FIFO or a device is refused unopened
            loaded = np.load(fh, allow_pickle=False)
            if not isinstance(loaded, np.lib.npyio.NpzFile):
                raise RecordError(f"{path} is not a readable .npz archive (a single .npy array): {_CORRUPT}")
            with loaded as z:
                missing = [n for n in names if n not in z.files]
                if missing:
                    lacks = ", ".join(missing)
                    raise RecordError(f"{path} is not a readable .npz archive (it lacks {lacks}): {_CORRUPT}")
                out = {}
                for name in (*names, *(n for n in optional if n in z.files)):
                    out[name] = z[name]
                return out
    except ReadRefused as exc:
        if exc.reason == "missing":
            raise RecordError(f"{path} does not exist (the record is incomplete): {_CORRUPT}") from None
        raise RecordError(f"{path} is {exc.why}: {_CORRUPT}" if exc.reason != "size" else str(exc)) from None
    except RecordError:
        raise
    except NPZ_ERRORS as exc:
        raise _npz_refusal(path, exc, name) from None


def pairs_from_json(d: dict[str, Any]) -> tuple[PairRecord, ...]:
    """The pair records of a parsed ``record.json``."""
    return tuple(PairRecord(**{**p, "h": _fit_from(p["h"]), "f": _fit_from(p["f"])}) for p in d["pairs"])


def read_record(path: str | Path) -> ClipRecord:
    """Read a record from its folder or its ``record.json``. Raises :class:`RecordError` (one
    sentence naming the file) for a record that is missing, corrupt, pickled, too large or lacks
    fields."""
    folder, d = read_record_json(path)
    cells_names = tuple(f"cells_{name}" for name in CellArrays.NAMES)
    dense_names = tuple(f"dense_{name}" for name in (*DENSE_NAMES, "offsets"))
    pointmaps_names = tuple(f"pointmaps_{name}" for name in PointMaps.NAMES)
    z = read_matches(
        folder,
        MatchArrays.NAMES,
        (
            *MatchArrays.OPTIONAL,
            *cells_names,
            "cloud_xyz",
            "cloud_rgb",
            *dense_names,
            *pointmaps_names,
            *MV_ARRAYS,
            *MAP_ARRAYS,
            *REGION_ARRAYS,
            RECORD_ID_ARRAY,
        ),
    )
    try:
        _check_counts(d, z, folder / "record.json")
        record = _record_from(d, z)
    except RecordError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError) as exc:  # missing fields, wrong shapes or types
        raise RecordError(
            f"{folder / 'record.json'} is not a readable GeoCon record ({type(exc).__name__}: {exc}): {_CORRUPT}"
        ) from None
    other = record.other_model()  # the clip model's own sentence when its file cannot be used
    if other is not None and record.made_with is None:
        raise RecordError(
            f"{folder / 'record.json'} was made with the clip model {other[0]}, which this GeoCon does not have (its "
            f"model is {other[1]}), and its summary holds no verdict that could be the one it was made with: "
            f"{_CORRUPT}"
        )
    return record


def _check_same_record(d: dict[str, Any], z: dict[str, np.ndarray], folder: Path) -> None:
    """``matches.npz`` holds the id ``record.json`` names (both none: a record written before ids)."""
    want = d.get("record_id")
    got = None
    if RECORD_ID_ARRAY in z:
        stored = z[RECORD_ID_ARRAY]
        got = str(stored.reshape(-1)[0]) if stored.dtype.kind == "U" and stored.size == 1 else repr(stored)
    if want != got:
        raise RecordError(
            f"{folder / 'matches.npz'} belongs to another record (its record id is {got or 'missing'}, "
            f"{folder / 'record.json'} names {want or 'none'}): copy a record folder whole, or score the clip again"
        )


MAX_WORKING_SIDE = 16384
"""The largest side of a working canvas a record may name (px): a larger one is not a record GeoCon
wrote (its canvas is never larger than the configured working size), and would be allocated."""


def _check_counts(d: dict[str, Any], z: dict[str, np.ndarray], file: Path) -> None:
    """The counts and sizes of a record that the readers and viewers allocate by (the frame count,
    the canvas, the row offsets of ``matches.npz``) agree with what the record holds: its pairs,
    its per-frame lists and, once ``matches.npz`` is known to be this record's
    (:func:`_check_same_record`), its arrays; a :class:`RecordError` naming the field and the file
    otherwise (an edited or damaged record), before anything is allocated."""

    def refuse(what: str) -> RecordError:  # one sentence naming the file and the field
        return RecordError(f"{file}: {what}: the record was edited or damaged; score the clip again")

    video, pairs = d["video"], d["pairs"]
    n = video["num_frames"]
    if not isinstance(n, int) or isinstance(n, bool) or n < 2:
        raise refuse(f"video.num_frames is {n!r}, not a frame count")
    fps = video["fps"]
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not (math.isfinite(fps) and 0 < fps < MAX_FPS):
        raise refuse(f"video.fps is {fps!r}, not a frame rate (above 0 and below {MAX_FPS:g} frames/s)")
    gaps = [int(g) for g in d["config"]["gaps"]]
    t1s = [int(p["t1"]) for p in pairs]
    if pairs and n != max(t1s) + 1:
        raise refuse(f"video.num_frames is {n} but its pairs end at frame {max(t1s)} ({max(t1s) + 1} frames)")
    if not pairs and gaps and n > min(gaps):
        raise refuse(f"video.num_frames is {n} but it holds no frame pair (a clip of {n} frames has some)")
    for p in pairs:
        if not (0 <= int(p["t0"]) < int(p["t1"]) < n) or not 0 <= int(p["index"]) < len(pairs):
            raise refuse(f"pair {p['index']} ({p['t0']}, {p['t1']}) lies outside its {n} frames or {len(pairs)} pairs")
    for name in ("masked_share", "dynamic_share"):
        values = d.get(name) or []
        if len(values) not in (0, n):
            raise refuse(f"{name} has {len(values)} values for video.num_frames {n}")
    for e in d.get("object_entries", []):
        if not 0 <= int(e["t0"]) < int(e["t1"]) < n:
            raise refuse(f"an object entry on frames ({e['t0']}, {e['t1']}) lies outside its {n} frames")
    cfg_w, cfg_h = (int(v) for v in d["config"]["working_size"])
    w, h = (int(v) for v in video["working_size"])
    if not (0 < w <= min(cfg_w, MAX_WORKING_SIDE) and 0 < h <= min(cfg_h, MAX_WORKING_SIDE)):
        raise refuse(f"video.working_size {w}x{h} is larger than the configured {cfg_w}x{cfg_h} or empty")
    _check_same_record(d, z, file.parent)  # before the arrays are measured against this record's counts
    _check_offsets(z, "offsets", "x1", len(pairs), file, refuse)
    if "cells_offsets" in z:
        _check_offsets(z, "cells_offsets", "cells_weights", len(d.get("object_entries", [])), file, refuse)


def _check_offsets(
    z: dict[str, np.ndarray], name: str, rows: str, count: int, file: Path, refuse: Callable[[str], RecordError]
) -> None:
    """``z[name]`` holds the ``count + 1`` row offsets of ``count`` entries into ``z[rows]``: from 0,
    rising, ending at its length."""
    offsets = z[name]
    total = len(z[rows]) if rows in z else 0
    if (
        offsets.ndim != 1
        or offsets.dtype.kind not in "iu"
        or len(offsets) != count + 1
        or offsets[0] != 0
        or np.any(np.diff(offsets) < 0)
        or offsets[-1] != total
    ):
        raise refuse(
            f"the {len(offsets)} {name} of {file.parent / 'matches.npz'} do not fit its {count} entries and "
            f"{total} rows of {rows}"
        )


def _record_from(d: dict[str, Any], z: dict[str, np.ndarray]) -> ClipRecord:
    """The :class:`ClipRecord` of a parsed ``record.json`` and its ``matches.npz`` arrays."""
    matches = MatchArrays(**{name: z[name] for name in (*MatchArrays.NAMES, *MatchArrays.OPTIONAL) if name in z})
    cells = CellArrays(**{name: z[f"cells_{name}"] for name in CellArrays.NAMES}) if "cells_offsets" in z else None
    cloud = None
    if d.get("cloud") is not None:
        cloud = PointCloud(xyz=z["cloud_xyz"], rgb=z["cloud_rgb"], note=d["cloud"]["note"])
    pointmaps = None
    if d.get("pointmaps") is not None:  # records before DUSt3R have no such key
        p = d["pointmaps"]
        pointmaps = PointMaps(
            **{name: z[f"pointmaps_{name}"] for name in PointMaps.NAMES},
            frames=tuple(p["frames"]),
            box=tuple(p["box"]),
            input_size=tuple(p["input_size"]),
            step=p["step"],
            note=p["note"],
        )
    gate = GateRecord.from_json_dict(d["gate"])
    b = d["background"]
    background = BackgroundSummary(**{**b, "chosen": _family_from(b["chosen"]), "other": _family_from(b["other"])})
    pairs = pairs_from_json(d)
    return ClipRecord(
        clip=d["clip"],
        video=ClipInfo.from_dict(d["video"]),
        config=ScoreConfig.from_dict(d["config"]),
        config_hash=d["config_hash"],
        versions=d["versions"],
        gate=gate,
        background=background,
        pairs=pairs,
        matches=matches,
        intrinsics=d["intrinsics"],
        category=None if d["category"] is None else Category(**d["category"]),
        warnings=tuple(d["warnings"]),
        masks_source=d["masks_source"],
        masked_share=tuple(d["masked_share"]),
        objects=tuple(
            ObjectSummary(**{**o, "per_scale": tuple(ObjectScaleSummary(**p) for p in o["per_scale"])})
            for o in d["objects"]
        ),
        object_entries=tuple(ObjectEntry(**e) for e in d["object_entries"]),
        cells=cells,
        cloud=cloud,
        dense=_dense_from(d.get("dense", []), z),
        pointmaps=pointmaps,
        shots=tuple(ShotRecord(**s) for s in d.get("shots", [])),
        dynamic_share=tuple(float(v) for v in d.get("dynamic_share", [])),
        multiview=None if d.get("multiview") is None else MultiViewResult.from_parts(d["multiview"], z),
        readings=None if d.get("readings") is None else ClipReadings.from_json_dict(d["readings"], z),
        regions=None if d.get("regions") is None else RegionsPart.from_json_dict(d["regions"], z),
        record_id=d.get("record_id"),
        made_with=stored_finding(d.get("summary")),
    )


def record_problem(folder: str | Path) -> str | None:
    """What keeps the record in ``folder`` from being read, in one sentence, checked without
    reading its arrays: its ``record.json`` missing, damaged or of another format
    (:func:`read_record_json`), its ``matches.npz`` missing, cut short or of another record (the
    ids both hold); None when it is whole. Resumed runs (``geocon bench``, ``geocon validate``)
    score a clip again when its record has a problem."""
    try:
        folder, d = read_record_json(folder)
    except RecordError as exc:
        return str(exc)
    npz = folder / "matches.npz"
    if not npz.is_file() or not zipfile.is_zipfile(npz):  # its directory is at its end: a cut file has none
        return f"{npz} is missing or not a whole .npz archive"
    try:
        _check_same_record(d, read_matches(folder, (), (RECORD_ID_ARRAY,)), folder)
    except RecordError as exc:
        return str(exc)
    return None


def pinned_model(d: dict[str, Any]) -> str | None:
    """The digest of the clip model a parsed ``record.json`` was made with, where the clip model
    decided it (its configuration's ``signals`` on and readings recorded): its
    ``signals.model_sha256`` (empty: any model); None where the background decided."""
    signals = d.get("config", {}).get("signals") if isinstance(d.get("config"), dict) else None
    if d.get("readings") is None or not isinstance(signals, dict) or not signals.get("enabled"):
        return None
    pinned = signals.get("model_sha256", "")
    return pinned if isinstance(pinned, str) else ""


def stored_finding(summary: Any) -> ClipFinding | None:
    """The finding a ``record.json`` summary holds (``verdict``, ``clip_score``, ``why``), or None
    when it holds none that could be one: a verdict of :data:`~.finding.VERDICT_WORDS` with a
    reason, a clip score between 0 and 1 (or none), contributions that are finite numbers."""
    if not isinstance(summary, dict) or not isinstance(summary.get("verdict"), dict):
        return None
    verdict, reason = summary["verdict"].get("verdict"), summary["verdict"].get("reason")
    score, why = summary.get("clip_score"), summary.get("why", {})
    if verdict not in VERDICT_WORDS or not isinstance(reason, str) or not isinstance(why, dict):
        return None
    if score is not None and (isinstance(score, bool) or not isinstance(score, (int, float)) or not 0 <= score <= 1):
        return None
    parts = tuple(why.items())
    if any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) for _, v in parts):
        return None
    return ClipFinding(verdict, reason, None if score is None else float(score), tuple((k, float(v)) for k, v in parts))
