// Unit tests of "the newest load draws": `node --test tests/` (run by the pytest suite).
import assert from "node:assert/strict";
import test from "node:test";

import { newestLoads } from "../js/lib/newest.js";

function deferred() {
  let resolve;
  const promise = new Promise((r) => (resolve = r));
  return { promise, resolve };
}

test("a load that began earlier but answers last does not draw", async () => {
  const begin = newestLoads();
  const shown = [];
  const load = async (answer) => {
    const current = begin();
    const record = await answer.promise;
    if (current()) shown.push(record);
  };
  const a = deferred();
  const b = deferred();
  const loadingA = load(a);
  const loadingB = load(b);
  b.resolve("B");
  await loadingB;
  a.resolve("A");
  await loadingA;
  assert.deepEqual(shown, ["B"]);
});

test("one load at a time always draws", async () => {
  const begin = newestLoads();
  const first = begin();
  assert.equal(first(), true);
  const second = begin();
  assert.equal(first(), false);
  assert.equal(second(), true);
});
