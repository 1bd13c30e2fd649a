"""``geocon pose-log``: a pose log (``geocon-pose/1``) from a COLMAP model or a DUSt3R scene run
elsewhere, for ``geocon score --pose-log``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Callable, Optional

import typer

from .console import fail, out

__all__ = ["pose_log"]


def pose_log(
    source: Annotated[
        Path,
        typer.Argument(
            help="A COLMAP sparse model in text format (a folder with images.txt and points3D.txt) or a DUSt3R "
            "scene saved as .npz (poses: cam-to-world (N, 4, 4); pts3d: the first view's point map)."
        ),
    ],
    out_file: Annotated[Path, typer.Option("--out", help="The pose log to write (JSON).")],
    first: Annotated[
        Optional[str], typer.Option(help="COLMAP: name of the clip's first frame (default: first by name).")
    ] = None,
    last: Annotated[
        Optional[str], typer.Option(help="COLMAP: name of the clip's last frame (default: last by name).")
    ] = None,
) -> None:
    """Turn a reconstruction made elsewhere (COLMAP, DUSt3R) into the pose log that `geocon score
    --pose-log` reads: the first -> last relative pose on the scale of the first camera's mean
    scene distance."""
    from geocon_core.files import check_apart, check_out_file, claim
    from geocon_core.pose import PoseLog, from_colmap, from_dust3r, write_pose_log

    try:
        check_apart([("--out", out_file)], [("COLMAP model" if source.is_dir() else "DUSt3R scene", source)])
        check_out_file(out_file, "--out", "pose.json")
        claim("--out", out_file, "json:geocon-pose", mine=_converted_from(None))
        if source.is_dir():
            log = from_colmap(source, first, last)
        else:
            if first is not None or last is not None:
                raise ValueError("--first and --last name COLMAP images; a DUSt3R scene uses its first and last view")
            log = from_dust3r(source)
        claim("--out", out_file, "json:geocon-pose", mine=_converted_from(log["source"]))
        write_pose_log(log, out_file)
    except ValueError as exc:
        raise fail(str(exc)) from None
    t_inf = PoseLog(out_file).t_inf
    out.print(
        f"pose log: {out_file} ({log['source']}; t_inf {t_inf:.4f} on the unit mean scene distance)", soft_wrap=True
    )


def _converted_from(source: str | None) -> Callable[[Any], str | None]:
    """The ``mine`` test of a pose log ``--out`` may replace: one ``geocon pose-log`` wrote (its
    ``source`` names a COLMAP model or a DUSt3R scene) from the same model or scene as ``source``
    (its words before the colon: ``dust3r scene.npz``); any such log when ``source`` is None."""

    def mine(there: Any) -> str | None:
        was = (there.data or {}).get("source")
        if not isinstance(was, str) or not was.startswith(("colmap ", "dust3r ")):
            return "a pose log `geocon pose-log` did not write (written by hand or by another program)"
        if source is not None and was.split(":")[0] != source.split(":")[0]:
            return f"the pose log of {was.split(':')[0]}, not of {source.split(':')[0]}"
        return None

    return mine
