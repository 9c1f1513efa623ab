// The pause / resume / stop buttons of a run (a trial or a collection): each names its action in
// `data-run-action`, and a click posts it to the run's one control route, `{path}/{id}/{action}`.
import { api } from "./api.js";
import { ACTIVE } from "./states.js";
import { guarded } from "./ui.js";

/** The control buttons inside the element with id `containerId`. */
export function runControls(containerId) {
  return [...document.getElementById(containerId).querySelectorAll("[data-run-action]")];
}

/** Post a button's action for the run `current()` gives (nothing without one), then `reload(id)`. */
export function bindRunControls(buttons, path, current, reload) {
  for (const button of buttons) {
    button.addEventListener("click", () =>
      guarded(async () => {
        const run = current();
        if (!run) return;
        await api(`${path}/${run.id}/${button.dataset.runAction}`, { method: "POST" });
        await reload(run.id);
      }, button),
    );
  }
}

/** Enable the actions a run of `status` allows (none for a finished run or no status). */
export function enableRunControls(buttons, status) {
  for (const button of buttons) {
    const action = button.dataset.runAction;
    button.disabled =
      !ACTIVE.includes(status) ||
      (action === "pause" && status !== "running") ||
      (action === "resume" && status !== "paused");
  }
}
