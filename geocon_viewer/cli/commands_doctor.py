"""``geocon doctor``: which backends, viewers and extras are usable on this machine, and for the
others what is missing and how to get it."""

from __future__ import annotations

import importlib.util
import os
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version

from rich.table import Table

from .console import VIEWER_EXTRA, out

__all__ = ["doctor", "Check", "checks"]


@dataclass(frozen=True)
class Check:
    """One component: ``group`` (flow, masks, pose, viewer, ...), ``name`` (as the command line
    spells it), whether it is usable here and a sentence: what it runs on, or what it needs."""

    group: str
    name: str
    usable: bool
    detail: str


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
        Check("core", "decoding", _have("av") and _have("cv2"), f"PyAV {_version('av')}, OpenCV {cv}"),
        Check("core", "transport (AdaDFRC-W2)", _have("ot"), f"POT {_version('POT')}"),
        Check(
            "core",
            "bundle adjustment (multi-view check, audit)",
            _have("pycolmap"),
            f"pycolmap {_version('pycolmap')}"
            if _have("pycolmap")
            else "pycolmap is missing: pip install 'pycolmap==4.2.*'",
        ),
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
    from ..chromium import find_chromium

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


def _unmet(torch_ok: bool, torch_text: str, modules: tuple[str, ...], install: str) -> str | None:
    """Why a torch backend cannot run here (torch, or the ``modules`` it imports, are missing, and
    ``install`` gets them), or None."""
    if not torch_ok:
        return torch_text
    missing = [m for m in modules if not _have(m)]
    return f"needs {', '.join(missing)}: {install}" if missing else None


def _sam2(torch_ok: bool, torch_text: str) -> Check:
    """Whether SAM-2's video predictor imports (it also needs torch), and how to get it."""
    from geocon_core.masks.sam2 import SAM2_INSTALL, sam2_config_names

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
    from geocon_core.pose.dust3r import DUST3R_INSTALL

    elsewhere = "; or run DUSt3R elsewhere and pass --pose-log"
    unmet = _unmet(torch_ok, torch_text, ("mini_dust3r", "einops", "beartype", "huggingface_hub"), DUST3R_INSTALL)
    if unmet is not None:
        return Check("pose", "dust3r", False, unmet + elsewhere)
    try:
        from geocon_core.pose.dust3r import import_model_class

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


def doctor() -> None:
    """Which backends, viewers and extras are usable on this machine, and for the others what to
    install or pass."""
    table = Table(title="GeoCon on this machine", title_justify="left")
    for column in ("", "component", "usable", "what it runs on, or what it needs"):
        table.add_column(column)
    for c in checks():
        table.add_row(c.group, c.name, "[green]yes[/]" if c.usable else "[yellow]no[/]", c.detail)
    out.print(table)
