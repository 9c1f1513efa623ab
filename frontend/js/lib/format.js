// Number formatting shared by the pages and the pure helpers (no DOM: unit-tested with node).

// A number to `digits` significant digits; exponent form when very large or small; "—" when
// missing or not finite.
export function num(value, digits = 4) {
  if (value === null || value === undefined || !Number.isFinite(Number(value))) return "—";
  const n = Number(value);
  if (n !== 0 && (Math.abs(n) >= 1e5 || Math.abs(n) < 1e-3)) return n.toExponential(Math.max(0, digits - 1));
  return Number(n.toPrecision(digits)).toString();
}
