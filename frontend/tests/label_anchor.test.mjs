// Unit tests of chart label placement: `node --test tests/` (run by the pytest suite).
import assert from "node:assert/strict";
import test from "node:test";

import { labelAnchor } from "../js/lib/label_anchor.js";

test("a label that fits goes right of its point", () => {
  assert.deepEqual(labelAnchor(100, 80, 400), { x: 107, align: "left" });
  assert.deepEqual(labelAnchor(313, 80, 400), { x: 320, align: "left" }); // ends exactly at the edge
});

test("a label that would leave the canvas goes left of its point", () => {
  assert.deepEqual(labelAnchor(314, 80, 400), { x: 307, align: "right" });
  assert.deepEqual(labelAnchor(390, 80, 400, 5), { x: 385, align: "right" });
});
