"""``activetouch bench``: the performance figures, printed side by side with ratios.

Register with ``app.command("bench")(bench_command)``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from app.cli.output import messages as stderr
from bench.run import Options, report, run


def bench_command(
    quick: Annotated[
        bool, typer.Option("--quick", help="A reduced run that finishes in under 2 minutes.")
    ] = False,
    as_json: Annotated[
        bool, typer.Option("--json", help="Print every figure as one JSON object on stdout.")
    ] = False,
    plot: Annotated[Path, typer.Option(help="Where to write the scaling plot (PNG).")] = Path(
        "artifacts/bench/scaling.png"
    ),
    threads: Annotated[
        list[int] | None,
        typer.Option(help="BLAS thread counts to time (repeat the option); default 1 and 2."),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of the worlds and data.")] = 0,
) -> None:
    """Benchmark the likelihood, the fit, the mutual information, planning and scaling against
    GPy and the direct formulas (medians of repeats, BLAS threads pinned)."""
    counts = tuple(threads) if threads else (1, 2)
    if any(t < 1 for t in counts):
        raise typer.BadParameter(
            f"thread counts must be ≥ 1, received {counts}", param_hint="--threads"
        )

    def progress(message: str) -> None:
        stderr.print(f"[dim]bench:[/dim] {escape(message)}")

    figures = run(Options(quick=quick, threads=counts, plot=plot, seed=seed, progress=progress))
    if as_json:
        document = {**figures["headline"], "figures": figures}
        sys.stdout.write(json.dumps(document, default=float) + "\n")
    else:
        sys.stdout.write(report(figures) + "\n")
