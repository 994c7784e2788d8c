"""``sptpt-annotate eval``: OTB one-pass scores of results against ground truth."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np
import typer

from annotator.commands.common import fail
from annotator.errors import EXIT_INPUT, EXIT_OUTPUT, EXIT_VALUE, ToolError, require_extra
from annotator.output_files import CALIBRATION_PLOT
from annotator.wording import plural


def eval_command(
    results: Path = typer.Argument(..., help="A results file or output folder (one sequence), or a folder of <Seq>.txt / <Seq>/ results (dataset)."),
    ground_truth: Path = typer.Argument(..., help="A ground-truth file (one sequence) or an OTB-layout root (dataset)."),
    out: Optional[Path] = typer.Option(None, "--out", help="Folder for plots and tables (default: print the table only)."),
    tracker_name: str = typer.Option("sptpt", "--name", help="Tracker name in tables and plots."),
    sequences: Optional[str] = typer.Option(
        None, "--sequences", metavar="NAME,NAME",
        help="Dataset mode: score only these sequences (e.g. those a batch with --stop finished)."),
    overlap: bool = typer.Option(
        False, "--overlap",
        help="Score the frames a run and its ground truth both hold when the ground truth has another length than "
             "the run's video (refused otherwise)."),
    debug: bool = typer.Option(False, "--debug", help="Show tracebacks."),
) -> None:
    """Score results against ground truth: OTB success AUC (IoU > t, 21 thresholds) and precision at 20 px."""
    from annotator.evaluation import (
        DatasetScore,
        EvaluationError,
        MissingInputError,
        evaluate_result_file,
        evaluate_results_dir,
        results_markdown,
        write_report,
    )
    from annotator.evaluation.calibration import failure_markdown, failure_summary, plot_calibration
    from annotator.otb_format import OTBFormatError

    pairs: list = []
    try:
        if out is not None and out.exists() and not out.is_dir():
            raise ToolError(f"--out {out} is a file: give a folder for the plots and tables", EXIT_OUTPUT)
        if out is not None:
            require_extra("eval --out")
        try:
            if ground_truth.is_dir():
                names = [n.strip() for n in sequences.split(",") if n.strip()] if sequences is not None else None
                if names == []:
                    raise ToolError(f"--sequences {sequences!r} names no sequence: give names such as "
                                    "--sequences Coke,David", EXIT_VALUE)
                skipped: list[str] = []
                score = evaluate_results_dir(ground_truth, results, tracker=tracker_name, sequences=names, pairs=pairs,
                                             overlap=overlap, skipped=skipped)
                if skipped:
                    typer.echo(f"scored the {plural(len(score.sequences), 'sequence')} {results} holds; "
                               f"{plural(len(skipped), 'sequence')} of {ground_truth} without a result left out: "
                               f"{', '.join(skipped)}", err=True)
            else:
                if sequences is not None:
                    raise ToolError("--sequences picks sequences of a dataset: give an OTB-layout root as "
                                    "GROUND_TRUTH, or drop --sequences", EXIT_VALUE)
                sequence = evaluate_result_file(results, ground_truth, pairs=pairs, overlap=overlap)
                score = DatasetScore.from_sequences(tracker_name, [sequence])
        except FileNotFoundError as exc:
            raise ToolError(f"{exc.filename or exc}: not found: give an existing results path and ground truth", EXIT_INPUT) from None
        except MissingInputError as exc:
            raise ToolError(str(exc), EXIT_INPUT) from None
        except (EvaluationError, OTBFormatError) as exc:
            raise ToolError(str(exc), EXIT_VALUE) from None
        for pair, _ in pairs:
            if pair.note:
                typer.echo(pair.note, err=True)
        typer.echo(results_markdown([score]))
        failure = failure_summary(pairs)
        if failure is not None:
            typer.echo(failure_markdown(failure))
        if out is not None:
            try:
                written = write_report(out, [score])
                if failure is not None:
                    scored = [(pair, seq) for pair, seq in pairs if pair.p_fail is not None]
                    p_fail = np.concatenate([pair.p_fail for pair, _ in scored])
                    failed = np.concatenate([~(seq.ious >= 0.5) for _, seq in scored])
                    written["calibration"] = plot_calibration(out / CALIBRATION_PLOT,
                                                              {tracker_name: (p_fail, failed)})
            except OSError as exc:
                raise ToolError(f"--out {out} cannot be written ({exc.strerror or exc}): choose a writable folder "
                                "(the table above is complete)", EXIT_OUTPUT) from None
            typer.echo(f"plots and tables written to {out}: {', '.join(p.name for p in written.values())}", err=True)
    except ToolError as error:
        fail(error, debug)
