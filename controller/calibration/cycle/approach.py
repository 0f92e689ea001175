"""Anti-backlash approach: every measuring move ends with both axes moving up.

A geared axis lags its motor by up to the backlash after a reversal, so the same commanded
step count puts the mirror at two poses depending on the side it came from. Ending every
measuring move in the same direction (steps increasing) by more than the backlash, after a
move down that also exceeds it, leaves the gear always loaded the same way: the pose a
measurement records is the pose the same steps give later, which is what the fitted model
is used for. Daytime tracking with the model's steps must approach the same way.
"""

from __future__ import annotations

MARGIN_STEPS = 8  # beyond the configured backlash, for play the configuration underestimates


def approach_path(current: tuple[int, int] | None, target: tuple[int, int], backlash: tuple[int, int],
                  limits) -> list[tuple[int, int]]:
    """Waypoints from ``current`` (None: unknown) to ``target`` (motor steps) so that each
    axis arrives moving up by more than its backlash: a pre-position below the target when an
    axis starts above it or too close below, else the target alone. ``limits``: the drive's
    soft limits (``limits.az.min_steps`` …), which the pre-position respects. The move down to
    the pre-position is itself longer than the backlash (from just below the target it goes
    ``need`` below the present steps), so each reversal takes up the whole play."""
    pre = []
    for cur, tgt, b, lo in zip(current or (None, None), target, backlash,
                               (limits.az.min_steps, limits.el.min_steps), strict=True):
        need = b + MARGIN_STEPS
        if b > 0 and (cur is None or cur > tgt - need):
            # The move down travels at least ``need`` too: a reversal shorter than the play
            # leaves the gear between its flanks, and the next reversal starts from there.
            pre.append(max(lo, tgt - need if cur is None else min(tgt, cur) - need))
        else:
            pre.append(None)
    if pre == [None, None]:
        return [target]
    first = tuple(p if p is not None else t for p, t in zip(pre, target, strict=True))
    return [first, target] if first != target else [target]
