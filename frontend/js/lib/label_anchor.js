// Where a point's text label goes in a chart: pure, so it is tested with node.

/**
 * The anchor of a label drawn beside a point at `x`: to its right (`align` "left") when the text
 * fits before `right`, the right edge of the drawing area, else to its left (`align` "right"), so a
 * point near the right edge keeps its whole name on the canvas.
 * @param {number} x the point's horizontal position (px)
 * @param {number} textWidth the label's measured width (px)
 * @param {number} right the drawing area's right edge (px)
 * @param {number} gap space between point and text (px)
 * @returns {{x: number, align: "left" | "right"}}
 */
export function labelAnchor(x, textWidth, right, gap = 7) {
  if (x + gap + textWidth <= right) return { x: x + gap, align: "left" };
  return { x: x - gap, align: "right" };
}
