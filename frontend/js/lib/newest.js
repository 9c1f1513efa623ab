// Overlapping loads of one view: only the newest may draw. Pure, so it is tested with node.

/**
 * A counter of loads: each call marks a new load as the newest and returns its check, true while
 * no later load has begun. A page that loads record A, then B, draws B even when A's response
 * arrives last (a reload of A, fired by A's late events, must not replace B).
 * @returns {() => () => boolean}
 */
export function newestLoads() {
  let begun = 0;
  return () => {
    begun += 1;
    const mine = begun;
    return () => mine === begun;
  };
}
