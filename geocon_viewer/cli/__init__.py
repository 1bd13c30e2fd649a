"""The ``geocon`` command line. Every command is a plain function in a ``commands_*`` module,
registered here by name; the commands import the core and the viewers they need when they run,
so ``geocon --help`` loads neither Rerun nor Viser.

==================  ============================================================================
``synth``           synthetic clips with exact ground truth (:mod:`.commands_synth`)
``synth-failures``  the injectable failures
``demo``            render, describe and score a small synthetic clip (:mod:`.commands_demo`)
``score``           score one clip (:mod:`.commands_score`)
``synth-bench``     a synthetic benchmark dataset
``bench``           score a dataset, write tables (:mod:`.commands_bench`)
``report``          the paper's tables and figures from benchmark results
``presets``         the named scoring presets
``view``            a saved record in the Rerun viewer (:mod:`.commands_view`)
``serve``           a results folder in the Viser audit app
``teach``           a synthetic scene in the Viser teaching app (:mod:`.commands_teach`)
``validate``        the validation report: synthetic grid and annotated real clips (:mod:`.commands_validate`)
``footage``         the footage cache of the validation: status, fill from local clones
``pose-log``        a pose log from a COLMAP model or a DUSt3R scene (:mod:`.commands_pose`)
``doctor``          which backends, viewers and extras are usable here (:mod:`.commands_doctor`)
==================  ============================================================================
"""

from __future__ import annotations

from typing import Annotated

import typer

from geocon_core import __version__

from . import (
    commands_bench,
    commands_demo,
    commands_doctor,
    commands_pose,
    commands_score,
    commands_synth,
    commands_teach,
    commands_validate,
    commands_view,
)
from .console import out

__all__ = ["app", "main"]

app = typer.Typer(
    name="geocon",
    help="GeoCon: is a generated video geometrically real? Ground-truth-free audit of background and object "
    "consistency.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _version_callback(value: bool) -> None:
    if value:
        out.print(f"geocon {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool, typer.Option("--version", callback=_version_callback, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    """GeoCon: is a generated video geometrically real?"""


app.command("synth")(commands_synth.synth)
app.command("synth-failures")(commands_synth.synth_failures)
app.command("demo")(commands_demo.demo)
app.command("score")(commands_score.score)
app.command("synth-bench")(commands_synth.synth_bench)
app.command("bench")(commands_bench.bench)
app.command("report")(commands_bench.report)
app.command("presets")(commands_bench.presets)
app.command("view")(commands_view.view)
app.command("serve")(commands_view.serve)
app.command("teach")(commands_teach.teach)
app.command("validate")(commands_validate.validate)
app.command("footage")(commands_validate.footage)
app.command("pose-log")(commands_pose.pose_log)
app.command("doctor")(commands_doctor.doctor)


def main() -> None:
    """The ``geocon`` console script."""
    app()
