"""The acceptance check of docs/calibration.md ("Acceptance"): is the recogniser right when it
says it is sure, and does choosing the touch pay, with the documented commands' defaults?

Runs the commands a new user would (each printed; an output already in ``--workdir`` is reused,
so an interrupted run resumes and anyone can rerun it):

    activetouch collect --sim --table T --touches 100 --seed S --out train.csv
    activetouch collect --sim --table T --touches 100 --design random --placements 100 \\
        --seed S+1 --out heldout.csv      (and heldout-2.csv … heldout-4.csv, seeds S+2 … S+4)
    activetouch fit train.csv --out model.json
    activetouch evaluate --model model.json --world rig --table T \\
        --policies active,discriminative,passive --trials n --steps 6 --workers W --seed S \\
        --out eval-rig-n<n>-T6-s<S>.json
    activetouch evaluate ... --world model ...  --out eval-model-n<n>-T6-s<S>.json
    activetouch evaluate ... --world replay --data heldout.csv ... \\
        --out eval-replay-n<n>-T6-s<S>.json

(``--table-file F`` in place of ``--table T``; the first collection takes ``collect``'s default
design, the adaptive one, with its default placements, or ``--placements P``; each held-out
collection is a random design with a fresh placement for every touch, as recorded data are,
never seen by the fit and as large as the training collection; n = ⌈trials / objects⌉ trials
per target.) ``--heldout-sessions K`` (4 by default) held-out sessions are collected the same
way (seeds S+1 … S+K, a fresh simulated rig each), replayed one by one, and the replay's
criteria judged on their trials pooled (:func:`pooled_report`); each session's own figures are
printed too. One session's thermal offset is one draw shared by all its replayed trials
(docs/calibration.md, "Replay on four held-out sessions of the cushions"), and a small session
offers the planners few of the touches that discriminate ("How noisy a replay's ECE is"):
hence four sessions of the training collection's size. The trials run in the
evaluation engine behind ``activetouch evaluate`` (Dask ``LocalCluster`` of ``--workers``); this
module only reads the reports.

It prints, per world, policy and touch: accuracy with its 95 % interval, ECE and the answers
given with p ≥ 0.95 that were wrong; then one PASS/FAIL line per criterion of the acceptance
(:func:`assess`): sure answers ≥ 95 % right and ECE ≤ 0.05 for every policy (rig and replay;
each ECE with its over- and under-confident parts, :func:`confidence_gaps`, which say which way
a failing one misses);
active and discriminative never below passive beyond the intervals (rig; active on replay); on
the cushions ≥ 90 % at T and ≥ 15 points ahead of passive at some touch ≤ 5; world model vs
rig within 10 points at T for every policy. ``paper exp1`` and ``bench/correlated_noise`` are
separate benches and are named as not run here.

Run: ``python -m bench.trust_acceptance (--table cushions | --table-file F) [--trials 200]
[--workers 2] [--steps 6] [--touches 100] [--heldout-touches 100] [--heldout-sessions 4] [--seed 0]
[--no-press-depth] [--workdir DIR] [--json OUT]``. Exit code 1 when a criterion fails.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from core.evaluation.records import TrialRecord
from core.evaluation.summary import summarise

#: The policies compared, the planners first.
POLICIES = ("active", "discriminative", "passive")
PLANNERS = ("active", "discriminative")

#: Thresholds of the acceptance (docs/calibration.md, "Acceptance").
SURE = 0.95
MAX_SHARE_WRONG = 0.05
MAX_ECE = 0.05
CUSHIONS_AT_T = 0.90
CUSHIONS_LEAD = 0.15
CUSHIONS_LEAD_BY_TOUCH = 5
MAX_MODEL_RIG_GAP = 0.10

#: The worlds evaluated; world W's report is ``eval-W-n<trials per target>-T<steps>-s<seed>.json``
#: in the work directory (reused only with the same settings).
REPORTS = ("rig", "model", "replay")


@dataclass(frozen=True)
class Criterion:
    """One line of the acceptance: what is asked, whether it holds, and the figures behind it."""

    name: str
    passed: bool
    detail: str

    def line(self) -> str:
        return f"{'PASS' if self.passed else 'FAIL'}  {self.name}: {self.detail}"


# ---------------------------------------------------------------------------------------------
# Reading the reports (activetouch-evaluation/2) and judging them (tested in
# tests/bench/test_trust_acceptance.py on hand-made summaries)
# ---------------------------------------------------------------------------------------------


def _policy(document: Mapping[str, Any], policy: str) -> Mapping[str, Any]:
    try:
        summary: Mapping[str, Any] = document["policies"][policy]
    except KeyError:
        raise ValueError(
            f"the {document.get('world')!r} report has no policy {policy!r} (it has "
            f"{sorted(document.get('policies', {}))})."
        ) from None
    return summary


def _sure(calibration: Mapping[str, Any]) -> tuple[int, int]:
    """(sure, wrong) answers at p ≥ the report's threshold."""
    sure = calibration["sure_and_wrong"]
    return int(sure["sure"]), int(sure["wrong"])


def calibration_criteria(document: Mapping[str, Any], world: str) -> list[Criterion]:
    """Sure answers ≥ 95 % right, and ECE ≤ 0.05, for every policy (over every trial and touch)."""
    sure_parts, ece_parts = [], []
    sure_ok = ece_ok = True
    for policy in POLICIES:
        scored = _policy(document, policy)["calibration"]["all_touches"]
        sure, wrong = _sure(scored)
        share = wrong / sure if sure else 0.0
        sure_ok &= share <= MAX_SHARE_WRONG
        sure_parts.append(f"{policy} {wrong}/{sure}" + (f" ({100 * share:.1f} %)" if sure else ""))
        ece = scored["ece"]
        ece_ok &= ece is not None and ece <= MAX_ECE
        ece_parts.append(
            f"{policy} {'—' if ece is None else f'{ece:.3f}'}{_direction(scored)}{_null(scored)}"
        )
    return [
        Criterion(
            f"{world}: of the answers with p ≥ {SURE:g}, ≥ {100 * (1 - MAX_SHARE_WRONG):.0f} % "
            "right, every policy",
            sure_ok,
            "wrong/sure " + ", ".join(sure_parts),
        ),
        Criterion(
            f"{world}: ECE ≤ {MAX_ECE:g}, every policy", ece_ok, "ECE " + ", ".join(ece_parts)
        ),
    ]


def not_below_passive(
    document: Mapping[str, Any], world: str, policies: Sequence[str] = PLANNERS
) -> Criterion:
    """Each of ``policies`` never worse than passive beyond the 95 % intervals: at no touch
    does its interval's upper end lie below passive's lower end."""
    passive = _policy(document, "passive")["accuracy_interval"]
    below = []
    for policy in policies:
        intervals = _policy(document, policy)["accuracy_interval"]
        for touch, ((_, high), (low, _)) in enumerate(zip(intervals, passive, strict=True), 1):
            if high < low:
                below.append(f"{policy} at touch {touch} ({100 * high:.1f} < {100 * low:.1f})")
    return Criterion(
        f"{world}: {' and '.join(policies)} never below passive beyond the 95 % intervals",
        not below,
        "below: " + "; ".join(below) if below else "at every touch the intervals meet or lie above",
    )


def cushions_criteria(document: Mapping[str, Any]) -> list[Criterion]:
    """On the cushions (rig): ≥ 90 % at T, and ≥ 15 points ahead of passive at some touch ≤ 5,
    for active and discriminative."""
    passive = _policy(document, "passive")["accuracy_by_touch"]
    at_t, lead = [], []
    at_t_ok = lead_ok = True
    for policy in PLANNERS:
        curve = _policy(document, policy)["accuracy_by_touch"]
        at_t_ok &= curve[-1] >= CUSHIONS_AT_T
        at_t.append(f"{policy} {100 * curve[-1]:.1f} %")
        reach = min(CUSHIONS_LEAD_BY_TOUCH, len(curve))
        gaps = [curve[t] - passive[t] for t in range(reach)]
        best = max(range(reach), key=lambda t: gaps[t])
        lead_ok &= gaps[best] >= CUSHIONS_LEAD
        lead.append(f"{policy} +{100 * gaps[best]:.1f} points at touch {best + 1}")
    return [
        Criterion(
            f"rig (cushions): active and discriminative ≥ {100 * CUSHIONS_AT_T:.0f} % right at T",
            at_t_ok,
            ", ".join(at_t),
        ),
        Criterion(
            f"rig (cushions): active and discriminative ≥ {100 * CUSHIONS_LEAD:.0f} points ahead "
            f"of passive at some touch ≤ {CUSHIONS_LEAD_BY_TOUCH}",
            lead_ok,
            "largest lead: " + ", ".join(lead),
        ),
    ]


def model_rig_gap(model_world: Mapping[str, Any], rig: Mapping[str, Any]) -> Criterion:
    """World ``model`` vs world ``rig`` within 10 points at T, every policy."""
    parts, ok = [], True
    for policy in POLICIES:
        on_model = _policy(model_world, policy)["accuracy_by_touch"][-1]
        on_rig = _policy(rig, policy)["accuracy_by_touch"][-1]
        ok &= abs(on_model - on_rig) <= MAX_MODEL_RIG_GAP
        parts.append(f"{policy} {100 * on_model:.1f} vs {100 * on_rig:.1f}")
    return Criterion(
        f"model vs rig within {100 * MAX_MODEL_RIG_GAP:.0f} points at T, every policy",
        ok,
        "model vs rig: " + ", ".join(parts),
    )


def assess(documents: Mapping[str, Mapping[str, Any]], cushions: bool) -> list[Criterion]:
    """Every criterion of the acceptance the reports can decide.

    Args:
        documents: The ``activetouch-evaluation/2`` reports by world: ``rig``, ``model`` and
            ``replay`` (each with the policies active, discriminative and passive).
        cushions: Whether the table is the cushions (two criteria hold there only).

    Returns:
        The criteria in the order of docs/calibration.md "Acceptance".

    Raises:
        ValueError: A world or a policy is missing.
    """
    missing = [w for w in REPORTS if w not in documents]
    if missing:
        raise ValueError(f"documents: no report of the world(s) {missing}.")
    rig, replay = documents["rig"], documents["replay"]
    criteria = [*calibration_criteria(rig, "rig"), not_below_passive(rig, "rig")]
    if cushions:
        criteria += cushions_criteria(rig)
    criteria.append(model_rig_gap(documents["model"], rig))
    criteria.append(not_below_passive(replay, "replay", ("active",)))
    criteria += calibration_criteria(replay, "replay")
    return criteria


def pooled_report(sessions: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """One replay report of the trials of several held-out sessions together.

    The policies' summaries are :func:`core.evaluation.summary.summarise` of every session's
    trials at once, as ``activetouch evaluate`` summarises one session's: accuracy by touch, its
    intervals (on the effective number of trials: different sessions share no recorded touch),
    and the calibration over every answer.

    Args:
        sessions: ``activetouch-evaluation/2`` replay reports of one model, with the same
            objects, T and confidence threshold, and their ``trials``.

    Returns:
        A report with the fields :func:`assess` and :func:`touch_table` read; its
        ``trials_per_target``, ``seconds`` and ``sessions`` are summed over the sessions.

    Raises:
        ValueError: No session, or sessions that differ in objects, T or threshold.
    """
    if not sessions:
        raise ValueError("sessions: need at least one replay report to pool.")
    first = sessions[0]
    for key in ("objects", "steps", "confidence"):
        values = [s[key] for s in sessions]
        if any(v != values[0] for v in values):
            raise ValueError(f"sessions: the reports differ in {key!r}: {values}.")
    records = [TrialRecord.from_dict(t) for s in sessions for t in s["trials"]]
    if not records:
        raise ValueError("sessions: the reports hold no trials (written without them).")
    return {
        "world": f"{first['world']} ({len(sessions)} sessions pooled)",
        "trials_per_target": sum(int(s["trials_per_target"]) for s in sessions),
        "steps": first["steps"],
        "seconds": sum(float(s["seconds"]) for s in sessions),
        "workers": first["workers"],
        "sessions": len(sessions),
        "policies": summarise(records, first["objects"], first["steps"], first["confidence"]),
    }


def session_lines(sessions: Sequence[Mapping[str, Any]]) -> list[str]:
    """Per held-out session and policy: accuracy at touch 1 and T, ECE and sure and wrong."""
    lines = []
    for k, document in enumerate(sessions, 1):
        parts = []
        for policy in POLICIES:
            summary = _policy(document, policy)
            curve = summary["accuracy_by_touch"]
            scored = summary["calibration"]["all_touches"]
            sure, wrong = _sure(scored)
            ece = _ece_text(scored)
            parts.append(
                f"{policy} {100 * curve[0]:.0f} → {100 * curve[-1]:.1f} %, ECE {ece}, "
                f"{wrong}/{sure}"
            )
        lines.append(f"  session {k}: " + "; ".join(parts))
    return lines


def _ece_text(scored: Mapping[str, Any]) -> str:
    """A calibration summary's ECE to three decimals, "—" when it has none (no answers)."""
    return "—" if scored["ece"] is None else f"{scored['ece']:.3f}"


def confidence_gaps(scored: Mapping[str, Any]) -> tuple[float, float] | None:
    """(over, under): the ECE's part from reliability bins whose answers were stated surer than
    they were right, and from those stated less sure, Σ_b (n_b / n) max(0, ±(confidence_b −
    accuracy_b)); over + under is the ECE. ``None`` when the summary has no reliability table
    or no answers."""
    table = scored.get("reliability")
    if not table:
        return None
    total = sum(int(b["count"]) for b in table)
    if total == 0:
        return None
    over = under = 0.0
    for b in table:
        if b["count"] and b["accuracy"] is not None and b["mean_confidence"] is not None:
            gap = float(b["mean_confidence"]) - float(b["accuracy"])
            share = int(b["count"]) / total
            over += share * max(gap, 0.0)
            under += share * max(-gap, 0.0)
    return over, under


def _direction(scored: Mapping[str, Any]) -> str:
    """ " [over 0.xxx, under 0.xxx]": which way the answers miss, when the report has bins."""
    gaps = confidence_gaps(scored)
    return "" if gaps is None else f" [over {gaps[0]:.3f}, under {gaps[1]:.3f}]"


def _null(scored: Mapping[str, Any]) -> str:
    """ " (calibrated: mean, p95)": the ECE these answers would show by sampling alone were they
    calibrated (core.evaluation.calibration.ece_if_calibrated), when the report has it."""
    null = scored.get("ece_if_calibrated")
    return "" if not null else f" (if calibrated {null['mean']:.3f}, p95 {null['p95']:.3f})"


def touch_table(document: Mapping[str, Any]) -> list[str]:
    """Per policy and touch: accuracy % (95 % interval), ECE, wrong/sure at p ≥ 0.95, and the
    effective number of trials where trials share recorded touches (replay)."""
    lines = [
        f"world {document['world']}: {document['trials_per_target']} trials per target, "
        f"T = {document['steps']}, {document['seconds']:.0f} s on {document['workers']} "
        f"worker(s)"
        + (f", refused {document['refused_by_policy']}" if document.get("refused_trials") else "")
    ]
    for policy in POLICIES:
        summary = _policy(document, policy)
        lines.append(f"  {policy} ({summary['trials']} trials)")
        by_touch = summary["calibration"]["by_touch"]
        # Reports written before effective_trials: every trial counted.
        effective = summary.get("effective_trials") or [summary["trials"]] * len(by_touch)
        for touch, (accuracy, (low, high), scored, size) in enumerate(
            zip(
                summary["accuracy_by_touch"],
                summary["accuracy_interval"],
                by_touch,
                effective,
                strict=True,
            ),
            1,
        ):
            sure, wrong = _sure(scored)
            ece = _ece_text(scored)
            shared = f"  n_eff {size:.1f}" if size < summary["trials"] else ""
            lines.append(
                f"    touch {touch}: {100 * accuracy:5.1f} % ({100 * low:5.1f}–{100 * high:5.1f})"
                f"  ECE {ece}  sure & wrong {wrong}/{sure}{shared}"
            )
        scored = summary["calibration"]["all_touches"]
        sure, wrong = _sure(scored)
        ece = _ece_text(scored)
        lines.append(f"    all touches: ECE {ece}{_null(scored)}  sure & wrong {wrong}/{sure}")
    return lines


def comparison_lines(document: Mapping[str, Any]) -> list[str]:
    """Active and discriminative vs passive per touch, by their intervals."""
    passive = _policy(document, "passive")
    lines = []
    for policy in PLANNERS:
        summary = _policy(document, policy)
        verdicts = []
        for (a, (a_lo, a_hi)), (p, (p_lo, p_hi)) in zip(
            zip(summary["accuracy_by_touch"], summary["accuracy_interval"], strict=True),
            zip(passive["accuracy_by_touch"], passive["accuracy_interval"], strict=True),
            strict=True,
        ):
            verdict = "above" if a_lo > p_hi else "below" if a_hi < p_lo else "overlap"
            verdicts.append(f"{100 * (a - p):+.0f} ({verdict})")
        lines.append(f"  {policy} − passive by touch: " + ", ".join(verdicts))
    return lines


# ---------------------------------------------------------------------------------------------
# Running the documented commands
# ---------------------------------------------------------------------------------------------


def _run(command: list[str], out: Path) -> None:
    """Run ``command`` unless ``out`` exists (then reuse it); print it either way."""
    shown = " ".join(command[1:] if command[0].endswith("activetouch") else command)
    if out.exists():
        print(f"# reusing {out}: activetouch {shown}", flush=True)
        return
    print(f"$ activetouch {shown}", flush=True)
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)


def run(args: argparse.Namespace, workdir: Path) -> dict[str, dict[str, Any]]:
    """Collect, fit and evaluate with the documented commands; the reports by world."""
    exe = str(Path(sys.executable).parent / "activetouch")
    table = ["--table", args.table] if args.table else ["--table-file", str(args.table_file)]
    train, heldout, model = workdir / "train.csv", workdir / "heldout.csv", workdir / "model.json"
    seed = str(args.seed)
    placements = [] if args.placements is None else ["--placements", str(args.placements)]
    press = [] if args.press_depth else ["--no-press-depth"]
    _run(
        [exe, "collect", "--sim", *table, "--touches", str(args.touches), *placements, *press,
         "--seed", seed, "--out", str(train)],
        train,
    )  # fmt: skip
    sessions = args.heldout_sessions
    heldouts = [heldout, *(workdir / f"heldout-{k}.csv" for k in range(2, sessions + 1))]
    for k, path in enumerate(heldouts, 1):
        _run(
            [exe, "collect", "--sim", *table, "--touches", str(args.heldout_touches), "--design",
             "random", "--placements", str(args.heldout_touches), *press, "--seed",
             str(args.seed + k), "--out", str(path)],
            path,
        )  # fmt: skip
    _run([exe, "fit", str(train), "--out", str(model)], model)
    objects = len(json.loads(model.read_text())["objects"])
    per_target = max(1, math.ceil(args.trials / objects))
    documents = {}
    for world in REPORTS:
        extra = table if world == "rig" else ["--data", str(heldout)] if world == "replay" else []
        out = workdir / f"eval-{world}-n{per_target}-T{args.steps}-s{seed}.json"
        _run(
            [exe, "evaluate", "--model", str(model), "--world", world, *extra, "--policies",
             ",".join(POLICIES), "--trials", str(per_target), "--steps", str(args.steps),
             "--workers", str(args.workers), "--seed", seed, "--out", str(out)],
            out,
        )  # fmt: skip
        documents[world] = json.loads(out.read_text())
    if sessions > 1:
        replays = [documents["replay"]]
        for k, path in enumerate(heldouts[1:], 2):
            out = workdir / f"eval-replay-{k}-n{per_target}-T{args.steps}-s{seed}.json"
            _run(
                [exe, "evaluate", "--model", str(model), "--world", "replay", "--data",
                 str(path), "--policies", ",".join(POLICIES), "--trials", str(per_target),
                 "--steps", str(args.steps), "--workers", str(args.workers), "--seed", seed,
                 "--out", str(out)],
                out,
            )  # fmt: skip
            replays.append(json.loads(out.read_text()))
        print("\nreplay, each held-out session (accuracy touch 1 → T, ECE, wrong/sure):")
        print("\n".join(session_lines(replays)))
        documents["replay"] = pooled_report(replays)
    return documents


def report(documents: Mapping[str, Mapping[str, Any]], cushions: bool) -> list[Criterion]:
    """Print the per-touch tables, the comparisons and the verdicts; return the criteria."""
    for world in REPORTS:
        print()
        print("\n".join(touch_table(documents[world])))
        print("\n".join(comparison_lines(documents[world])))
    criteria = assess(documents, cushions)
    print("\nacceptance")
    for criterion in criteria:
        print(criterion.line())
    print(
        "NOT RUN HERE  paper exp1 and bench/correlated_noise calibration no worse than before: "
        "activetouch paper exp1; python -m bench.correlated_noise"
    )
    return criteria


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--table", help="A built-in simulated table (rig status --sim).")
    where.add_argument("--table-file", type=Path, help="A table file (docs/simulation.md).")
    parser.add_argument("--trials", type=int, default=200, help="Trials per policy and world.")
    parser.add_argument("--workers", type=int, default=2, help="evaluate --workers.")
    parser.add_argument("--steps", type=int, default=6, help="T.")
    parser.add_argument("--touches", type=int, default=100, help="Training touches per object.")
    parser.add_argument(
        "--heldout-touches", type=int, default=100, help="Held-out touches per object and session."
    )
    parser.add_argument(
        "--heldout-sessions",
        type=int,
        default=4,
        help="Held-out sessions replayed, their trials pooled for the replay's criteria.",
    )
    parser.add_argument(
        "--placements",
        type=int,
        help="collect --placements of the training collection (default: collect's default).",
    )
    parser.add_argument(
        "--no-press-depth",
        dest="press_depth",
        action="store_false",
        help="collect --no-press-depth (training and held-out): the six DMP components alone.",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workdir", type=Path, help="Keep (and reuse) every file here.")
    parser.add_argument("--json", type=Path, help="Also write the verdicts here.")
    args = parser.parse_args(argv)
    if min(args.trials, args.steps, args.workers, args.heldout_sessions) < 1:
        parser.error("--trials, --steps, --workers and --heldout-sessions must be ≥ 1")
    with tempfile.TemporaryDirectory() as temporary:
        workdir = args.workdir if args.workdir is not None else Path(temporary)
        workdir.mkdir(parents=True, exist_ok=True)
        documents = run(args, workdir)
        criteria = report(documents, cushions=args.table == "cushions")
    if args.json is not None:
        args.json.write_text(
            json.dumps([c.__dict__ for c in criteria], indent=1, ensure_ascii=False)
        )
    if not all(c.passed for c in criteria):
        sys.exit(1)


if __name__ == "__main__":
    main()
