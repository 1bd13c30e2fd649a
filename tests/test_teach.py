"""`geocon teach`, the Viser teaching app, driven from Python as a student drives it with the
sliders, and in headless Chromium by typing into the sliders' number boxes: moving the camera's
translation across the hysteresis band flips the gate label shown from H to F, breathing lowers the
strict (one-homography) IR shown, elasticity raises the disc's AdaDFRC shown, and a newer change
supersedes an older one.
Each update's latency (slider move to numbers on the page) is printed, not asserted; the 2 s
target is checked by benchmarks/bench_teach.py."""

from __future__ import annotations

import re
import socket

import numpy as np
import pytest

pytest.importorskip("viser")

from geocon_core.synth import build_scene  # noqa: E402
from geocon_viewer.shared.style import fmt  # noqa: E402
from geocon_viewer.teach.app import TeachApp, TeachParams, TeachUpdate  # noqa: E402


@pytest.fixture(scope="module")
def app():
    teach = TeachApp(port=0)
    teach.wait(timeout=180)  # the first clip (imports and warm-up included)
    yield teach
    port = teach.port
    teach.stop()
    with socket.socket() as s:  # nothing listens on the port any more (a browser's closed connection may linger)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))
        s.listen()


def _log(capsys, what: str, u: TeachUpdate) -> None:
    with capsys.disabled():
        print(
            f"\n    teach {what}: update {u.index} in {u.latency_s:.2f} s (render {u.render_s:.2f} s, "
            f"score {u.score_s:.2f} s): gate {u.gate_label}, IR {fmt(u.ir)}, strict IR {fmt(u.strict_ir)}, "
            f"AdaDFRC {fmt(u.adadfrc(), '.2f')}",
            end="",
        )


def _at(app: TeachApp, capsys, params: TeachParams) -> TeachUpdate:
    """The app showing ``params`` (one update unless it already does)."""
    if app.last is not None and app.last.params == params and app.last.record is not None:
        return app.last
    app.set_params(params)
    u = app.wait(timeout=120)
    _log(capsys, "baseline", u)
    return u


def _move(app: TeachApp, capsys, name: str, value: float) -> TeachUpdate:
    """Move one slider as a browser would (its callback runs) and wait for its update."""
    app.sliders[name].value = value
    u = app.wait(timeout=120)
    assert u.params == app.params and getattr(u.params, name) == value
    _log(capsys, f"{name} = {value:g}", u)
    return u


def _shown_label(app: TeachApp) -> str:
    m = re.search(r"<b>Gate <span[^>]*>([HUF])</span>", app.numbers.content)
    assert m, app.numbers.content[:300]
    return m.group(1)


@pytest.mark.full
def test_translation_across_the_band_flips_the_gate_from_H_to_F(app, capsys):
    assert app.host == "127.0.0.1"
    before = _at(app, capsys, TeachParams(translation=0.02))
    assert before.gate_label == "H" and _shown_label(app) == "H"
    after = _move(app, capsys, "translation", 0.07)
    assert after.gate_label == "F" and _shown_label(app) == "F"
    assert after.record is not None and after.record.gate.t_inf >= after.record.config.tau_t_high
    assert "fundamental matrix" in after.explanation and "H → F" in after.explanation
    assert after.explanation in app.explain_md.content
    assert after.clip is not None and abs(after.clip.t_inf_truth - 0.07) < 0.005  # the path rendered


@pytest.mark.full
def test_breathing_lowers_the_strict_ir_shown(app, capsys):
    before = _at(app, capsys, TeachParams())
    after = _move(app, capsys, "breathing_px", 12.0)
    assert before.strict_ir is not None and after.strict_ir is not None
    assert after.strict_ir < before.strict_ir - 0.03
    assert f"strict IR (one homography, H) <b>{fmt(after.strict_ir)}</b>" in app.numbers.content
    assert after.explanation.startswith("Background breathing 12 px")


@pytest.mark.full
def test_the_slide_slider_flags_the_clip_through_the_one_camera_check(app, capsys):
    before = _at(app, capsys, TeachParams(rotation_deg=3.0))
    assert before.record is not None and before.record.multiview is not None
    assert not before.record.multiview.layers and before.record.background.consistent
    after = _move(app, capsys, "slide_px", 12.0)
    rec = after.record
    assert rec is not None and rec.multiview is not None and rec.multiview.layers
    assert rec.background.consistent is False and "drifts against the camera path" in rec.finding().reason
    assert "one camera for the clip" in app.numbers.content and "drifts against the camera path" in app.numbers.content
    assert "does not fit one camera" in after.explanation
    assert app.server.scene  # the reconstruction's points are drawn beside the two-view cloud


@pytest.mark.full
def test_elasticity_raises_the_objects_adadfrc(app, capsys):
    before = _at(app, capsys, TeachParams())
    after = _move(app, capsys, "elastic_px", 20.0)
    a0, a1 = before.adadfrc(), after.adadfrc()
    assert a0 is not None and a1 is not None and a1 > 2.0 * a0 + 0.2
    assert after.clip is not None and after.clip.object_names[after.clip.deforming_id] == "disc"
    assert f"disc (deformed by the elasticity slider): AdaDFRC <b>{fmt(a1, '.2f')} px²</b>" in app.numbers.content
    assert "AdaDFRC of the disc" in after.explanation
    # the frame of the pair shown carries the background matches (green and red) over the picture
    img = app.image.image
    assert img.shape[1] == 640 and img.std() > 20


@pytest.mark.full
def test_a_newer_change_supersedes_an_older_one(app, capsys):
    _at(app, capsys, TeachParams())
    shown = len(app.updates)
    app.sliders["translation"].value = 0.03
    app.sliders["translation"].value = 0.09
    u = app.wait(timeout=120)
    _log(capsys, "superseded", u)
    assert u.params.translation == 0.09
    assert [x.params.translation for x in app.updates[shown:]] == [0.09]  # 0.03 never reached the page


def test_camera_and_object_speed_parameters_of_the_scene():
    """The additive scene parameters ``geocon teach`` relies on: a linear camera path to the pose
    given, and objects that stay put at speed 0; the defaults keep the family's scene."""
    plain = build_scene("C4", width=64, height=36, num_frames=5)
    same = build_scene("C4", width=64, height=36, num_frames=5, object_speed=1.0)
    assert np.array_equal(plain.T_cam_world, same.T_cam_world)
    assert all(np.array_equal(a.T_world_obj, b.T_world_obj) for a, b in zip(plain.objects, same.objects, strict=True))
    moved = build_scene("C4", width=64, height=36, num_frames=5, camera_end_center=(0.4, 0.0, 0.0))
    last = moved.T_cam_world[-1]
    assert np.allclose(-last[:3, :3].T @ last[:3, 3], [0.4, 0.0, 0.0]) and np.allclose(moved.T_cam_world[0], np.eye(4))
    still = build_scene("C4", width=64, height=36, num_frames=5, object_speed=0.0)
    assert all(np.allclose(o.T_world_obj, o.T_world_obj[0]) for o in still.objects)
    assert np.array_equal(still.background[0].texture, plain.background[0].texture)
    with pytest.raises(ValueError, match="object_speed"):
        build_scene("C4", object_speed=-1.0)


_FOCUS = """((label) => {
  const el = [...document.querySelectorAll('*')].find(e => e.childElementCount === 0 && e.textContent.trim() === label);
  let row = el;
  for (let i = 0; i < 8 && row && !row.querySelector('input[type=text]'); i++) row = row.parentElement;
  const input = row && row.querySelector('input[type=text]');
  if (!input) return null;
  input.focus(); input.select(); return input.value;
})(%s)"""
"""Focus and select the number box of the slider labelled so (the box a user types a value into)."""


def _type(page, app: TeachApp, capsys, label: str, name: str, value: float) -> str:
    """Type ``value`` into the slider ``label`` in the browser, wait for the app's update with it and
    for the page to show that update; returns the page's text."""
    import json
    import time

    assert page.evaluate(_FOCUS % json.dumps(label)) is not None, f"no slider labelled {label!r} on the page"
    page.type_text(f"{value:g}")
    page.press("Enter", key_code=13)
    end = time.monotonic() + 120
    while not (app.last is not None and getattr(app.last.params, name) == value and app.last.record is not None):
        assert time.monotonic() < end, f"no update with {name} = {value:g} arrived from the browser"
        time.sleep(0.05)
    u = app.last
    page.wait_for(f"document.body.innerText.includes('update {u.index}:')", timeout=30)
    _log(capsys, f"browser: {label} = {value:g}", u)
    return str(page.evaluate("document.body.innerText"))


def _number(text: str, pattern: str) -> float:
    m = re.search(pattern, text)
    assert m, (pattern, text[:600])
    return float(m.group(1))


@pytest.mark.full
def test_headless_chromium_drives_the_sliders(app, capsys):
    """A user's browser: typing into the sliders' number boxes moves the translation across the
    band (the gate label shown flips from H to F), raises breathing (the strict IR shown falls) and
    elasticity (the disc's AdaDFRC shown rises); the page shows the frame and the controls."""
    from geocon_viewer.capture.chromium import open_page
    from geocon_viewer.capture.screenshot import find_chromium

    if find_chromium() is None:
        pytest.skip("no Chromium on this machine (bash scripts/bootstrap.sh test installs it)")
    import cv2

    _at(app, capsys, TeachParams())
    with open_page(app.url, timeout_s=120) as page:
        page.wait_for("document.body.innerText.includes('camera translation')", timeout=60)
        text = page.wait_for("document.body.innerText.includes('Gate H') && document.body.innerText")
        strict = r"strict IR \(one homography, H\) ([0-9.]+)"
        disc = r"disc \(deformed by the elasticity slider\): AdaDFRC ([0-9.]+)"
        ir0, ada0 = _number(text, strict), _number(text, disc)
        text = _type(page, app, capsys, "camera translation", "translation", 0.07)
        assert "Gate F" in text and "Gate H" not in text
        _type(page, app, capsys, "camera translation", "translation", 0.02)
        text = _type(page, app, capsys, "background breathing (px)", "breathing_px", 12.0)
        assert _number(text, strict) < ir0 - 0.02
        _type(page, app, capsys, "background breathing (px)", "breathing_px", 0.0)
        text = _type(page, app, capsys, "object elasticity (px)", "elastic_px", 20.0)
        assert _number(text, disc) > ada0 + 0.2
        img = cv2.imdecode(np.frombuffer(page.screenshot(), np.uint8), cv2.IMREAD_COLOR)
    assert img is not None and img.shape[:2] == (1000, 1600)

    def busy(region: np.ndarray) -> float:
        """Share of pixels that differ from the region's most common colour (0: blank)."""
        flat = region.reshape(-1, 3)
        _, counts = np.unique(flat, axis=0, return_counts=True)
        return 1.0 - counts.max() / len(flat)

    assert busy(img[60:420, 20:650]) > 0.3, "the frame panel shows the rendered frame"
    assert busy(img[:, 1200:]) > 0.05, "the control panel shows the sliders"


# --- the command --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "args, words",
    [(["--port", "70000"], "--port must be between 0 and 65535"), (["--frames", "2"], "frames must be between 4")],
)
def test_cli_refuses_bad_options_before_serving(args, words):
    from typer.testing import CliRunner

    from geocon_viewer.cli import app as cli

    res = CliRunner().invoke(cli, ["teach", *args])
    assert res.exit_code != 0 and words in res.output


@pytest.mark.slow
def test_cli_serves_prints_each_updates_latency_and_stops_on_ctrl_c():
    import signal
    import subprocess
    import sys
    import urllib.request

    proc = subprocess.Popen(
        [sys.executable, "-m", "geocon_viewer.cli", "teach", "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = ""
        while "GeoCon teach:" not in line:
            line = proc.stdout.readline()
            assert line or proc.poll() is None, proc.stderr.read() if proc.stderr else ""
        assert "this machine only" in line
        url = line.split("GeoCon teach:", 1)[1].split()[0]
        port = int(url.rsplit(":", 1)[1])
        with urllib.request.urlopen(url, timeout=10) as resp:
            assert resp.status == 200
        while not line.startswith("update 1:"):
            line = proc.stdout.readline()
            assert line, proc.stderr.read() if proc.stderr else ""
        assert re.match(r"update 1: \d+\.\d\d s from the change to the numbers", line) and "gate H" in line
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=60)
        assert proc.returncode == 0, stderr
        assert "stopping" in stderr
    finally:
        proc.kill()
        proc.wait()
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))
