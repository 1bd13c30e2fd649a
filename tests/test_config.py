"""The scoring configuration is complete and typed: every field of every sub-configuration
changes the config hash and is printed by ``geocon presets``; dicts round-trip exactly; the
earlier flat layout still loads; each stage takes its own sub-configuration."""

from __future__ import annotations

import dataclasses
import json
from typing import Any, Callable

import numpy as np
import pytest
from typer.testing import CliRunner

from geocon_core.config.presets import (
    PRESETS,
    SUB_CONFIGS,
    UNUSED_BACKENDS,
    BarConfig,
    CategoryConfig,
    CutConfig,
    FlowConfig,
    MotionConfig,
    PoseConfig,
    ScanConfig,
    ScoreConfig,
    config_hash,
    config_items,
    preset,
)
from geocon_core.flow import DisFlow, make_flow_backend
from geocon_core.masks import MotionSegmenter, make_mask_source
from geocon_core.media.reader import _hard_cuts
from geocon_core.pose import ClassicalPose, make_pose_backend
from geocon_core.scoring import categorize
from geocon_viewer.cli import app

from .conftest import clip_info

# other valid values of the string fields (free names: any other name is valid)
_STRINGS = {
    "masks": "none",
    "aggregation": "worst",
    "flow_params.preset": "fast",
    "object_scales": "top",
    "signals.flow_preset": "fast",
}


def _changed(name: str, value: Any) -> list[Any]:
    """Candidate other values of one field, in order of preference."""
    if isinstance(value, bool):
        return [not value]
    if isinstance(value, int):
        return [value + 1, value - 1, value * 2]  # doubled: sizes that must stay multiples
    if isinstance(value, float):
        return [v for v in (value * 0.9, value * 1.1, value + 0.1, value + 0.5) if v != value]
    if isinstance(value, str):
        return [_STRINGS.get(name, value + "_other")]
    if isinstance(value, tuple):
        if name == "working_size":
            return [(value[0] + 1, value[1] + 1)]
        if all(isinstance(v, int) for v in value):
            return [(*value, max(value) + 1)]
        return [value[:-1], tuple(v * 0.9 for v in value)]
    raise AssertionError(f"no other value known for {name} = {value!r}")


def _variants() -> list[tuple[str, ScoreConfig]]:
    """One configuration per field (dotted name), that field changed to another valid value."""
    base = ScoreConfig()
    out = []
    for f in dataclasses.fields(base):
        value = getattr(base, f.name)
        if dataclasses.is_dataclass(value):
            for g in dataclasses.fields(value):
                sub_value = getattr(value, g.name)
                name = f"{f.name}.{g.name}"
                out.append((name, _first_valid(name, sub_value, _builder(base, f.name, g.name))))
        else:
            out.append((f.name, _first_valid(f.name, value, _builder(base, f.name, None))))
    return out


def _builder(base: ScoreConfig, top: str, sub: str | None) -> Callable[[Any], ScoreConfig]:
    """A function building ``base`` with the field ``top`` (or ``top.sub``) set to a value."""
    if sub is None:
        return lambda v: base.with_(**{top: v})
    return lambda v: base.with_(**{top: dataclasses.replace(getattr(base, top), **{sub: v})})


def _first_valid(name: str, value: Any, build: Callable[[Any], ScoreConfig]) -> ScoreConfig:
    for candidate in _changed(name, value):
        try:
            return build(candidate)
        except ValueError:
            continue
    raise AssertionError(f"no valid other value found for {name}")


VARIANTS = _variants()
AUDIT_HASH = "da4cef22a514ac9d"
"""The hash of ``audit`` (renewed whenever a setting of it changes)."""


def test_every_field_is_enumerated() -> None:
    names = [n for n, _ in VARIANTS]
    assert names == [n for n, _ in config_items(ScoreConfig())]
    for sub in SUB_CONFIGS:
        assert any(n.startswith(f"{sub}.") for n in names), sub
    assert len(names) >= 89


@pytest.mark.parametrize("name,config", VARIANTS, ids=[n for n, _ in VARIANTS])
def test_every_field_changes_the_hash(name: str, config: ScoreConfig) -> None:
    assert config != ScoreConfig()
    top = name.split(".")[0]
    if top in UNUSED_BACKENDS:
        # an optional backend's settings count once the backend is selected, and only then
        field, value = UNUSED_BACKENDS[top]
        assert config_hash(config) == config_hash(ScoreConfig()), name
        assert config_hash(config.with_(**{field: value})) != config_hash(ScoreConfig().with_(**{field: value}))
        return
    if top in ("multiview", "signals", "regions") and name != f"{top}.enabled":
        # the multi-view check's and the readings' settings count once they are on (audit), and only then
        assert config_hash(config) == config_hash(ScoreConfig()), name
        on = dataclasses.replace(getattr(config, top), enabled=True)
        base_on = dataclasses.replace(getattr(ScoreConfig(), top), enabled=True)
        assert config_hash(config.with_(**{top: on})) != config_hash(ScoreConfig().with_(**{top: base_on}))
        return
    assert config_hash(config) != config_hash(ScoreConfig()), name


def test_adding_an_optional_backend_keeps_the_hashes_of_the_presets() -> None:
    # the hashes the presets had when SAM-2 and DUSt3R were added (an optional backend's settings
    # leave them alone), as renewed on 2026-11-26 by the scoring settings added then (independent
    # motion, the still-camera test, shots, chain lengths, gate windows, the untrusted share, fades)
    # and on 2026-11-27 by the multi-view check in audit (paper, without it, kept its hash), then by
    # audit's objects at the largest scale only (a later setting at its old value leaves the hash alone)
    assert config_hash(preset("audit")) == AUDIT_HASH
    assert config_hash(preset("paper")) == "9406eeccc05e551f"


def test_presets_print_every_field() -> None:
    result = CliRunner().invoke(app, ["presets"], terminal_width=200)
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    for name, _ in VARIANTS:
        assert any(line.split("│")[1].strip() == name for line in lines if line.count("│") >= 3), name
    for preset_name in PRESETS:
        assert f"{preset_name}:" in result.output


def test_field_docstrings_exist() -> None:
    """Every field is documented (the docstring right below it in the class source)."""
    import inspect

    for cls in (ScoreConfig, *SUB_CONFIGS.values()):
        src = inspect.getsource(cls)
        for f in dataclasses.fields(cls):
            i = src.index(f"    {f.name}: ")
            following = src[i:].split("\n", 2)
            assert following[1].strip().startswith('"""'), f"{cls.__name__}.{f.name} has no docstring"


def test_round_trip_nested() -> None:
    cfg = ScoreConfig(
        gaps=(1, 4),
        motion=MotionConfig(min_area=0.002, halo_px=5),
        pose=PoseConfig(fit_focal=False),
        scans=ScanConfig(tau_h_grid=(1.0, 2.0)),
        flow_params=FlowConfig(preset="fast"),
    )
    d = json.loads(json.dumps(cfg.to_dict()))
    assert d["motion"]["min_area"] == 0.002
    assert d["scans"]["tau_h_grid"] == [1.0, 2.0]
    back = ScoreConfig.from_dict(d)
    assert back == cfg
    assert config_hash(back) == config_hash(cfg)
    for name, variant in VARIANTS:
        assert ScoreConfig.from_dict(json.loads(json.dumps(variant.to_dict()))) == variant, name


def test_previous_flat_layout_loads_with_defaults() -> None:
    flat = {k: v for k, v in ScoreConfig(gaps=(1, 4)).to_dict().items() if k not in SUB_CONFIGS}
    cfg = ScoreConfig.from_dict(flat)
    assert cfg == ScoreConfig(gaps=(1, 4))
    assert cfg.motion == MotionConfig() and cfg.category == CategoryConfig()


def test_unknown_keys_fail_with_one_sentence() -> None:
    with pytest.raises(ValueError, match=r"^unknown config keys: bogus$"):
        ScoreConfig.from_dict({"bogus": 1})
    with pytest.raises(ValueError, match=r"^unknown config\.motion keys: bogus$"):
        ScoreConfig.from_dict({"motion": {"bogus": 1}})
    with pytest.raises(ValueError, match="must be a mapping"):
        ScoreConfig.from_dict({"pose": 3})


def test_invalid_sub_config_values_are_refused() -> None:
    for bad in (
        lambda: MotionConfig(analysis_size=(8, 4)),
        lambda: PoseConfig(trim=0.6),
        lambda: FlowConfig(preset="slow"),
        lambda: FlowConfig(fb_abs=-1.0),
        lambda: CutConfig(hist_bins=0),
        lambda: BarConfig(min_content_share=2.0),
        lambda: ScanConfig(tau_h_grid=()),
    ):
        with pytest.raises(ValueError):
            bad()


@pytest.mark.parametrize("fov", [0.0, 9.9, 150.1, 179.99, float("nan")])
def test_a_field_of_view_outside_the_pinhole_range_is_refused(fov: float) -> None:
    with pytest.raises(ValueError, match=r"field of view \(fov_x_deg, --fov\) must be between 10 and 150 degrees"):
        ScoreConfig(fov_x_deg=fov)
    assert ScoreConfig(fov_x_deg=150.0).fov_x_deg == 150.0


# --- each stage takes its own sub-configuration ------------------------------------------------


def test_factories_pass_the_sub_config() -> None:
    flow = make_flow_backend("dis", FlowConfig(preset="fast", margin=4))
    assert isinstance(flow, DisFlow) and flow.config == FlowConfig(preset="fast", margin=4)
    assert make_flow_backend("dis").config == FlowConfig()
    pose = make_pose_backend("classical", PoseConfig(trim=0.1))
    assert isinstance(pose, ClassicalPose) and pose.config.trim == 0.1
    assert make_pose_backend("classical").config == PoseConfig()
    src = make_mask_source("motion", clip_info(), MotionConfig(min_track=3), flow=flow, seed=2)
    assert isinstance(src, MotionSegmenter) and src.config.min_track == 3 and src.flow is flow
    assert make_mask_source("motion", clip_info()).config == MotionConfig()  # type: ignore[attr-defined]
    # single-field keywords still work and override the config
    assert MotionSegmenter(clip_info(), MotionConfig(min_track=3), min_track=4).config.min_track == 4


def test_category_rule_takes_its_config() -> None:
    kw: dict[str, Any] = dict(
        gate_model="H",
        pose_present=True,
        t_inf=0.01,
        rotation_deg=0.2,
        background_motion_px=0.7,
        valid_share=1.0,
        median_matches=400.0,
        background_ir=0.99,
        object_frames=[5],
    )
    assert categorize(**kw).label == "C2"
    assert categorize(**kw, config=CategoryConfig(static_motion_px=1.0)).label == "C4"
    assert categorize(**kw, config=CategoryConfig(static_motion_px=1.0, min_object_frames=6)).label == "C1"
    low = categorize(**{**kw, "median_matches": 40.0})
    assert low.label == "C6" and "fewer than 50 background" in low.rule
    assert categorize(**kw, config=CategoryConfig(min_valid_share=1.5)).rule.startswith("stress: fewer than 150%")


def test_cut_detection_takes_its_config() -> None:
    dist = np.array([0.01, 0.02, 0.5, 0.02, 0.01])
    mad = np.array([1.0, 1.0, 40.0, 1.0, 1.0])
    dup = np.zeros(5, bool)
    assert _hard_cuts(dist, mad, dup, CutConfig()) == (3,)
    assert _hard_cuts(dist, mad, dup, CutConfig(min_mad=50.0)) == ()
    assert _hard_cuts(dist, mad, dup, CutConfig(min_distance=0.6)) == ()
