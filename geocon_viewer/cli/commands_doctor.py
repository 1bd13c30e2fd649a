"""``geocon doctor``: which backends, viewers and extras are usable on this machine, and for the
others what is missing and how to get it; and which of the packages that can change a score differ
from the versions the validation report was measured with (constraints.txt)."""

from __future__ import annotations

import importlib.resources
import importlib.util
import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from rich.markup import escape
from rich.table import Table

from .console import VIEWER_EXTRA, fail, out

__all__ = [
    "doctor",
    "Check",
    "checks",
    "SCORE_PACKAGES",
    "VersionDrift",
    "constraints_source",
    "parse_constraints",
    "version_drift",
]


@dataclass(frozen=True)
class Check:
    """One component: ``group`` (flow, masks, pose, viewer, ...), ``name`` (as the command line
    spells it), whether it is usable here and a sentence: what it runs on, or what it needs.
    ``required``: part of the core install, which every command needs (the others come with an
    extra or a tool that only some commands use)."""

    group: str
    name: str
    usable: bool
    detail: str
    required: bool = False
    problem: str = ""
    """What is wrong, in a few words, for a required part that is not usable (said in the sentence
    doctor fails with); empty: its name says it."""


SCORE_PACKAGES = ("numpy", "opencv-python-headless", "av", "POT", "pycolmap", "scipy")
"""The core dependencies whose versions can change a score (decoding, features, flow, fitting,
transport, bundle adjustment), compared with constraints.txt."""


@dataclass(frozen=True)
class VersionDrift:
    """A package of :data:`SCORE_PACKAGES` whose ``installed`` version (None: not installed)
    differs from the version the validation report was ``measured`` with."""

    package: str
    installed: str | None
    measured: str

    def sentence(self) -> str:
        if self.installed is None:
            return f"{self.package} is not installed, the validation report was measured with {self.measured}"
        return (
            f"installed {self.package} {self.installed}, the validation report was measured with "
            f"{self.measured}: scores may differ"
        )


def _canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def parse_constraints(text: str) -> dict[str, str]:
    """The ``name==version`` lines of a pip constraints file, by canonical package name (lower
    case, runs of ``-_.`` as ``-``); comments and blank lines are skipped."""
    pins: dict[str, str] = {}
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if "==" in line:
            name, _, pinned = line.partition("==")
            pins[_canonical(name)] = pinned.strip()
    return pins


def constraints_source() -> tuple[str, str]:
    """The text of constraints.txt and where it was read: the repository's when geocon runs from
    a checkout, else the copy shipped in the installed package (``geocon_core/constraints.txt``)."""
    import geocon_core

    root = Path(geocon_core.__file__).resolve().parent.parent
    if (root / "pyproject.toml").is_file() and (root / "constraints.txt").is_file():
        return (root / "constraints.txt").read_text(), str(root / "constraints.txt")
    shipped = importlib.resources.files("geocon_core").joinpath("constraints.txt")
    return shipped.read_text(), "constraints.txt shipped in the geocon package"


def _same_release(installed: str, measured: str) -> bool:
    """Equal versions; a local label (``2.13.0+cpu``) is ignored unless the pin names one."""
    return installed == measured or ("+" not in measured and installed.split("+", 1)[0] == measured)


def version_drift(pins: Mapping[str, str], installed: Callable[[str], str | None] | None = None) -> list[VersionDrift]:
    """The packages of :data:`SCORE_PACKAGES` pinned in ``pins`` (:func:`parse_constraints`)
    whose ``installed`` version (default: the installed distribution's) differs, in that order."""
    installed = installed or _version
    drift = []
    for package in SCORE_PACKAGES:
        measured = pins.get(_canonical(package))
        if measured is None:
            continue
        have = installed(package)
        if have is None or not _same_release(have, measured):
            drift.append(VersionDrift(package, have, measured))
    return drift


def _version(dist: str) -> str | None:
    try:
        return version(dist)
    except PackageNotFoundError:
        return None


def _have(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def _torch() -> tuple[bool, str]:
    """Whether torch imports, and on what it would run."""
    if not _have("torch"):
        return False, "needs torch: pip install 'geocon[neural]' (torch 2.13.0)"
    try:
        import torch
    except Exception as exc:  # a broken install is reported, not raised
        return False, f"torch is installed but does not import ({type(exc).__name__}: {exc})"
    device = f"CUDA ({torch.cuda.get_device_name(0)})" if torch.cuda.is_available() else "CPU (no CUDA device)"
    return True, f"torch {torch.__version__} on {device}"


def checks() -> list[Check]:
    """Every component GeoCon can use, checked on this machine."""
    cv = _version("opencv-python-headless") or _version("opencv-python") or "?"
    torch_ok, torch_text = _torch()
    out_checks = [
        Check("core", "decoding", _have("av") and _have("cv2"), f"PyAV {_version('av')}, OpenCV {cv}", required=True),
        Check("core", "transport (AdaDFRC-W2)", _have("ot"), f"POT {_version('POT')}", required=True),
        Check(
            "core",
            "bundle adjustment (multi-view check, audit)",
            _have("pycolmap"),
            f"pycolmap {_version('pycolmap')}"
            if _have("pycolmap")
            else "pycolmap is missing: pip install 'pycolmap==4.2.*'",
            required=True,
        ),
        _clip_model(),
        Check("features", "sift, sift_octaves, orb, klt, klt_tracks", True, f"OpenCV {cv}"),
        Check("flow", "dis", True, f"OpenCV {cv} (default, no weights)"),
        Check(
            "flow",
            "raft",
            torch_ok,
            f"{torch_text}; pass --flow raft --raft-checkpoint raft-small.pth" if torch_ok else torch_text,
        ),
        Check("masks", "motion", True, "built in (default, no weights)"),
        Check("masks", "external", True, "label PNGs (also indexed DAVIS PNGs), per-object folders or .npz (--masks)"),
        _sam2(torch_ok, torch_text),
        Check("pose", "classical", True, "built in (default, no weights)"),
        Check("pose", "log", True, "a geocon-pose/1 JSON file (--pose-log), e.g. from DUSt3R run elsewhere"),
        _dust3r(torch_ok, torch_text),
    ]
    rerun = _version("rerun-sdk")
    rerun_text = f"rerun-sdk {rerun}" if rerun else VIEWER_EXTRA
    out_checks.append(Check("viewer", "rerun (geocon view, --rrd)", rerun is not None, rerun_text))
    viser = _version("viser")
    out_checks.append(
        Check("viewer", "viser (geocon serve)", viser is not None, f"viser {viser}" if viser else VIEWER_EXTRA)
    )
    out_checks.append(_open3d())
    from ..capture import find_chromium

    chromium = find_chromium()
    out_checks.append(
        Check(
            "viewer",
            "screenshots of the web viewer",
            chromium is not None,
            f"Chromium at {chromium}" if chromium else "needs Chromium (Debian package chromium)",
        )
    )
    display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    out_checks.append(
        Check(
            "viewer",
            "native Rerun window",
            display and rerun is not None,
            "a display is available" if display else "no display: geocon view serves the web viewer on 127.0.0.1",
        )
    )
    bench = [m for m in ("pandas", "pyarrow", "matplotlib") if not _have(m)]
    out_checks.append(
        Check(
            "bench",
            "tables and report",
            not bench,
            "pandas, pyarrow, matplotlib" if not bench else f"needs {', '.join(bench)}: pip install 'geocon[bench]'",
        )
    )
    out_checks.append(Check("machine", "cores", True, f"{os.cpu_count()} CPU cores"))
    return out_checks


def _clip_model() -> Check:
    """Whether the clip model every preset decides with (:mod:`geocon_core.signals.model`) is there,
    readable, and the model of the digest the presets pin."""
    from geocon_core.config import PRESETS
    from geocon_core.signals import ClipModelError, ClipModelMismatch, load_clip_model, model_path

    name = "clip model (the audit verdict)"
    pins = sorted({(cfg.signals.model, cfg.signals.model_sha256) for _, cfg in PRESETS.values()})
    try:
        models = [(load_clip_model(model, digest), model) for model, digest in pins]
    except ClipModelMismatch as exc:
        problem = f"{exc.path} has digest {exc.found}, the presets pin {exc.pinned}"
        return Check("core", name, False, str(exc), required=True, problem=problem)
    except ClipModelError as exc:
        return Check("core", name, False, str(exc), required=True, problem=exc.problem)
    shown = ", ".join(f"digest {m.digest()} ({len(m.terms)} readings, {model_path(model)})" for m, model in models)
    return Check("core", name, True, f"{shown}, as the presets pin", required=True)


def _unmet(torch_ok: bool, torch_text: str, modules: tuple[str, ...], install: str) -> str | None:
    """Why a torch backend cannot run here (torch, or the ``modules`` it imports, are missing, and
    ``install`` gets them), or None."""
    if not torch_ok:
        return torch_text
    missing = [m for m in modules if not _have(m)]
    return f"needs {', '.join(missing)}: {install}" if missing else None


def _sam2(torch_ok: bool, torch_text: str) -> Check:
    """Whether SAM-2's video predictor imports (it also needs torch), and how to get it."""
    from geocon_core.masks import SAM2_INSTALL, sam2_config_names

    unmet = _unmet(torch_ok, torch_text, ("sam2", "hydra", "iopath"), SAM2_INSTALL)
    if unmet is not None:
        return Check("masks", "sam2", False, unmet)
    try:
        import sam2.build_sam  # noqa: F401  (hydra and the model code: what a broken install fails on)
    except Exception as exc:
        return Check("masks", "sam2", False, f"sam2 is installed but does not import ({type(exc).__name__}: {exc})")
    return Check(
        "masks",
        "sam2",
        True,
        f"sam2 {_version('sam2')} ({len(sam2_config_names())} model configurations), {torch_text}; "
        "pass --masks sam2 --sam2-checkpoint sam2.1_hiera_tiny.pt",
    )


def _dust3r(torch_ok: bool, torch_text: str) -> Check:
    """Whether DUSt3R's model imports from the mini-dust3r package (a checkout given with
    --dust3r-path is checked when it is used), and how to get it."""
    from geocon_core.pose import DUST3R_INSTALL

    elsewhere = "; or run DUSt3R elsewhere and pass --pose-log"
    unmet = _unmet(torch_ok, torch_text, ("mini_dust3r", "einops", "beartype", "huggingface_hub"), DUST3R_INSTALL)
    if unmet is not None:
        return Check("pose", "dust3r", False, unmet + elsewhere)
    try:
        from geocon_core.pose import import_model_class

        _, source = import_model_class()
    except ValueError as exc:
        return Check("pose", "dust3r", False, f"mini-dust3r is installed but does not import ({exc}){elsewhere}")
    return Check(
        "pose",
        "dust3r",
        True,
        f"{source} (CC BY-NC-SA 4.0, non-commercial), {torch_text}; pass --pose dust3r --dust3r-checkpoint PATH",
    )


def _open3d() -> Check:
    if not _have("open3d"):
        return Check("viewer", "open3d (point-cloud clean-up)", False, VIEWER_EXTRA)
    try:
        import open3d  # noqa: F401  (loads libusb: the failure users meet)
    except Exception as exc:
        return Check(
            "viewer",
            "open3d (point-cloud clean-up)",
            False,
            f"installed but does not load ({exc}); on Debian install libusb-1.0-0",
        )
    return Check("viewer", "open3d (point-cloud clean-up)", True, f"open3d {_version('open3d')}")


def _print_versions() -> None:
    """Whether the score-changing packages are the versions the validation report was measured with."""
    try:
        text, source = constraints_source()
    except OSError as exc:
        out.print(f"[yellow]No constraints.txt to compare versions with ({escape(str(exc))}).[/]", soft_wrap=True)
        return
    pins = parse_constraints(text)
    drift = version_drift(pins)
    if not drift:
        same = ", ".join(f"{p} {pins[_canonical(p)]}" for p in SCORE_PACKAGES if _canonical(p) in pins)
        out.print(f"Versions as in the validation report ({escape(source)}): {same}.", soft_wrap=True)
        return
    out.print(f"[yellow]Versions that differ from the validation report's[/] ({escape(source)}):", soft_wrap=True)
    for d in drift:
        out.print(f"  [yellow]{escape(d.sentence())}[/]", soft_wrap=True)


def doctor() -> None:
    """Which backends, viewers and extras are usable on this machine, and for the others what to
    install or pass; which packages that can change a score differ from the versions the validation
    report was measured with. Exits with code 2 when a part of the core install is unusable; a
    missing extra is reported as optional."""
    table = Table(
        title="GeoCon on this machine",
        title_justify="left",
        caption="optional: an extra or tool that only some commands need; geocon score and demo run without it",
        caption_justify="left",
    )
    for column in ("", "component", "usable", "what it runs on, or what it needs"):
        table.add_column(column)
    found = checks()
    for c in found:
        usable = "[green]yes[/]" if c.usable else "[red]no[/]" if c.required else "[yellow]no (optional)[/]"
        table.add_row(c.group, c.name, usable, escape(c.detail))  # "geocon[bench]" is not markup
    out.print(table)
    _print_versions()
    broken = [c.name + (f": {c.problem}" if c.problem else "") for c in found if c.required and not c.usable]
    if broken:
        raise fail(f"the core install is incomplete ({'; '.join(broken)}): reinstall geocon")
