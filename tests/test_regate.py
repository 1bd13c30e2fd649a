"""Re-gating stored residuals: the sensitivity scan at the recorded thresholds equals the record."""

from __future__ import annotations

import numpy as np
import pytest

from geocon_core.config import preset
from geocon_core.record import read_record, write_record
from geocon_core.scoring import regate_family, score_clip, sensitivity_scan


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
        assert [(g.gap, g.ir, g.ge, g.valid_pairs) for g in r.per_gap] == [
            (g.gap, g.ir, g.ge, g.valid_pairs) for g in fams[family].per_gap
        ]
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


def test_whole_clip_regating_at_recorded_thresholds_is_the_record(record, tmp_path):
    """:func:`regate_clip` (from the record, and from the slim residuals read off disk) gives the
    recorded gate label, model, IR, GE and verdict exactly."""
    from geocon_core.scoring import Thresholds, load_residuals, regate_clip

    write_record(record, tmp_path)
    th = Thresholds.of(record.config)
    for source in (record, load_residuals(tmp_path)):
        v = regate_clip(source, th)
        bg, g = record.background, record.gate
        assert (v.label, v.model, v.margin) == (g.label, g.model, g.margin)
        assert (v.ir, v.ge, v.consistent) == (bg.ir, bg.ge, bg.consistent)
    assert th.changed(th) == {}


def test_moving_thresholds_changes_the_verdict_as_the_rules_say(record):
    """C3 (translation): t_inf is above 0.05, so raising the gate's thresholds past it turns the
    clip into an H clip scored by the homography, whose residuals are larger (parallax); the
    report gates flip the verdict exactly at the clip's own IR and GE."""
    from geocon_core.scoring import Thresholds, regate_clip

    th = Thresholds.of(record.config)
    base = regate_clip(record, th)
    t = record.gate.t_inf
    assert base.label == "F" and t > 0.05
    as_h = regate_clip(record, Thresholds(**{**th.__dict__, "tau_t_low": t + 0.01, "tau_t_high": t + 0.02}))
    assert as_h.label == "H" and as_h.model == "H" and as_h.margin == pytest.approx(0.01)
    assert as_h.ir == regate_family(record, "H", th.tau_h).ir
    assert (as_h.ge, as_h.ge_f) == (regate_family(record, "H", th.tau_h).ge, base.ge) and as_h.ge > base.ge
    between = Thresholds(
        **{**th.__dict__, "tau_t_low": t + 0.01, "tau_t_high": t + 0.02, "ge_gate": (base.ge + as_h.ge) / 2}
    )
    assert regate_clip(record, between).consistent is False and regate_clip(record, between).report_margin < 0
    assert regate_clip(record, Thresholds(**{**th.__dict__, "ge_gate": (base.ge + as_h.ge) / 2})).consistent is True
    at = Thresholds(**{**th.__dict__, "ir_gate": base.ir})
    above = Thresholds(**{**th.__dict__, "ir_gate": float(np.nextafter(base.ir, 2.0))})
    assert regate_clip(record, at).consistent is (base.ge <= th.ge_gate)
    assert regate_clip(record, above).consistent is False
    assert Thresholds(**{**th.__dict__, "tau_h": 3.0}).changed(th) == {"tau_h": (th.tau_h, 3.0)}
    with pytest.raises(ValueError, match="low threshold"):
        Thresholds(**{**th.__dict__, "tau_t_low": 0.1, "tau_t_high": 0.05})


def test_choose_model_and_report_rules():
    from geocon_core.scoring import choose_model, report_margin, report_verdict

    assert choose_model("U", True, 0.9, 0.95) == "F" and choose_model("U", True, 0.95, 0.95) == "H"
    assert choose_model("U", True, None, 0.5) == "F" and choose_model("H", False, 1.0, 0.0) == "F"
    assert report_verdict(0.97, 3.5, 0.97, 3.5) is True and report_verdict(None, None, 0.97, 3.5) is None
    assert report_margin(0.985, 1.75, 0.97, 3.5) == pytest.approx(0.5)
    assert report_margin(0.99, 7.0, 0.97, 3.5) == pytest.approx(-1.0)
