// A finished trial of an evaluation (#trials?evaluation=ID&trial=N), shown read-only in the
// Trials view: its touches' actions, mutual information, answers and object probabilities.
// A trial the rig refused a touch of (e.g. a servo overload) shows the touches made before the
// refusal, if any, as for any trial, then the refused touch — its action and the device's
// reason — marked as refused, and no final answer (it counts neither as right nor as wrong).

import { lineChart, manifoldChart, posteriorChart } from "../charts.js";
import { $, el, fill, num, vec } from "../ui.js";
import { enableRunControls, runControls } from "../run_controls.js";

/** One labelled figure of the facts row. */
export function fact(label, value, testid) {
  return el("div", { class: "fact" }, el("div", { class: "label" }, label), el("div", { class: "value", "data-testid": testid }, value));
}

function touchesText(n) {
  return `${n} touch${n === 1 ? "" : "es"}`;
}

/** The result box: the final answer, or for a refused trial the refusal and no answer. */
function resultBox(r, refusal) {
  const origin = `trial index ${r.trial} of its (policy, target) cell, seed [${r.seed.join(", ")}]`;
  const result = $("trial-result");
  result.hidden = false;
  if (refusal) {
    result.className = "result refused";
    fill(
      result,
      `Refused by the rig at touch ${refusal.touch}: `,
      el("strong", { "data-testid": "trial-refusal" }, `${refusal.error}: ${refusal.reason}`),
      el(
        "div",
        { class: "small muted" },
        `no answer (a refused trial counts neither as right nor as wrong) · ${touchesText(r.touches)} made before it · refused action [${refusal.action.map((v) => num(v, 3)).join(", ")}] · ${origin}`,
      ),
    );
    return;
  }
  const answer = r.answers[r.touches - 1];
  result.className = `result ${r.correct ? "correct" : "wrong"}`;
  fill(
    result,
    "Answer: ",
    el("strong", { "data-testid": "trial-result-object" }, answer),
    r.correct ? " ✓ correct" : ` ✗ wrong (target ${r.target})`,
    el("div", { class: "small muted" }, `after ${touchesText(r.touches)} · ${r.stop_reason} · ${origin}`),
  );
}

/** Fill the Trials view with evaluation trial `record` (GET /evaluations/{id}/trials/{n}) of
 * `model` (GET /models/{id}). */
export function renderEvaluationTrial(record, model, evaluationId, number) {
  const r = record.record;
  const refusal = record.refused ? record.refusal || r.refused : null;
  const last = r.touches - 1; // -1: refused before any touch was made
  const probabilities = (t) => Object.fromEntries(record.objects.map((name, i) => [name, r.probabilities[t][i]]));
  const latest = last >= 0 ? probabilities(last) : {};
  const lastAnswer = last >= 0 ? r.answers[last] : null;
  const answer = refusal ? null : lastAnswer; // a refused trial has no final answer
  $("trial-title").textContent = `Evaluation #${evaluationId}, trial ${number} — ${r.policy}, target ${r.target}`;
  $("trial-status").textContent = refusal ? "refused by the rig" : "evaluation trial";
  $("trial-status").className = `badge ${refusal ? "failed" : "completed"}`;
  resultBox(r, refusal);
  fill(
    $("trial-facts"),
    fact("touches", refusal ? `${r.touches} (touch ${refusal.touch} refused)` : String(r.touches), "trial-touches"),
    refusal ? fact("answer", "none (refused)", "trial-nearest") : fact("answer", answer, "trial-nearest"),
    refusal
      ? fact("p(last answer)", lastAnswer === null ? "—" : `${lastAnswer} ${num(latest[lastAnswer], 3)}`)
      : fact("p(answer)", num(latest[answer], 3)),
    fact("last MI (nats)", last >= 0 ? num(r.mutual_information[last], 3) : "—"),
  );
  enableRunControls(runControls("trial-controls"), null);
  manifoldChart("chart-belief", model.objects, { nearest: answer });
  posteriorChart("chart-posterior", record.objects, latest, answer);
  lineChart(
    "chart-mi",
    [{ label: "I(s; y | x) of the chosen action", x: r.mutual_information.map((_, t) => t + 1), y: r.mutual_information }],
    { xTitle: "touch", yTitle: "mutual information (nats)", yMin: 0 },
  );
  $("plan-note").textContent = refusal
    ? `An evaluation trial the rig refused at touch ${refusal.touch}: the touches made before it and the refused one are listed below.`
    : "An evaluation trial: its actions are listed below.";
  fill(
    $("steps-body").parentElement.tHead,
    el("tr", {}, ["Touch", "Action x", "MI (nats)", "Answer", "p(answer)", "Object probabilities"].map((h) => el("th", { scope: "col" }, h))),
  );
  const rows = r.answers.map((a, t) =>
    el(
      "tr",
      { "data-testid": "step-row" },
      el("td", {}, t + 1),
      el("td", {}, vec(r.actions[t])),
      el("td", {}, num(r.mutual_information[t], 3)),
      el("td", {}, a),
      el("td", {}, num(probabilities(t)[a], 3)),
      el("td", {}, record.objects.map((name, i) => `${name} ${num(r.probabilities[t][i], 3)}`).join(", ")),
    ),
  );
  if (refusal) {
    rows.push(
      el(
        "tr",
        { "data-testid": "step-refused", class: "refused" },
        el("td", {}, refusal.touch),
        el("td", {}, vec(refusal.action)),
        el("td", {}, "—"),
        el("td", {}, "refused"),
        el("td", {}, "—"),
        el("td", {}, `${refusal.error}: ${refusal.reason}`),
      ),
    );
  }
  fill($("steps-body"), rows);
}
