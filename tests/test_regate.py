"""Re-gating stored residuals: the sensitivity scan at the recorded thresholds equals the record."""

from __future__ import annotations

import numpy as np
import pytest

from geocon_core.config import preset
from geocon_core.record import read_record, write_record
from geocon_core.regate import regate_family, sensitivity_scan
from geocon_core.scorer import score_clip


@pytest.fixture(scope="module", params=["paper", "strict"])
def record(request, synth_dir, tmp_path_factory):
    cfg = preset(request.param).with_(working_size=(320, 180), masks="none")
    rec = score_clip(synth_dir / "c3_translation.mp4", cfg)
    folder = tmp_path_factory.mktemp(f"rec-{request.param}")
    write_record(rec, folder)
    return read_record(folder)  # through the disk format, as the benchmark reads it


def test_scan_at_recorded_thresholds_equals_the_record_exactly(record):
    bg = record.background
    fams = {bg.chosen.family: bg.chosen, bg.other.family: bg.other}
    for family, tau in (("H", record.config.tau_h), ("F", record.config.tau_f)):
        r = regate_family(record, family, tau)
        assert r.ir == fams[family].ir and r.ge == fams[family].ge  # exact, not approximate
        assert r.valid_pairs == fams[family].valid_pairs
        assert [(g.gap, g.ir, g.ge, g.valid_pairs) for g in r.per_gap] == [(g.gap, g.ir, g.ge, g.valid_pairs) for g in fams[family].per_gap]
    scan = sensitivity_scan(record)
    defaults = [r for r in scan if r.tau == (record.config.tau_h if r.family == "H" else record.config.tau_f)]
    assert {r.family for r in defaults} == {"H", "F"}


def test_pair_inlier_ratios_grow_with_the_threshold(record):
    """Per pair, a looser threshold never loses an inlier: the pair IRs computed from the stored
    residuals are monotone in tau, and equal the recorded inlier counts at the recorded tau."""
    m = record.matches
    for p in record.pairs:
        if p.skip is not None or p.h is None or p.h.model is None:
            continue
        res = m.h_res[m.rows(p.index)]
        counts = [int(np.count_nonzero(res <= np.float32(t))) for t in (0.5, 1.0, 2.0, 4.0)]
        assert counts == sorted(counts)
        assert counts[2] == p.h.n_inliers


def test_a_loose_threshold_accepts_the_wrong_model_on_translation(record):
    """Under translation with parallax (C3), a homography's IR rises towards 1 only when its
    threshold is loosened far beyond the recorded 2 px; the scan shows the trade-off."""
    tight, loose = regate_family(record, "H", 0.5), regate_family(record, "H", 20.0)
    assert tight.ir is not None and loose.ir is not None
    assert loose.ir > tight.ir


def test_bad_family_is_rejected(record):
    with pytest.raises(ValueError, match="family must be 'H' or 'F'"):
        regate_family(record, "E", 1.0)  # type: ignore[arg-type]

