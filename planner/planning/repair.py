"""Repair: widen the separations that structured failures point at, for a re-colouring.

Acts on :class:`planner.planning.verify.Failure` records and on infeasible designs,
never on the readable failure text.
"""

from __future__ import annotations

import math

from planner.nodes import Node
from planner.planning.designs import design_offenders
from planner.planning.verify import IDLE_RESPONSE


def _widen(pair_sep, assignment, a, b, sep):
    # in positions (the channels where the design guard is narrower than the separation)
    where = assignment.positions or assignment.channels
    now = abs(where[a] - where[b]) // max(assignment.stride, 1)
    key = frozenset((a, b))
    pair_sep[key] = max(pair_sep.get(key, sep), now + max(1, sep // 2))


def widen_separations(failures, designs, steps, assignment, pair_sep, sep):
    """Update ``pair_sep`` (frozenset of two nodes -> separation [channels]) in place.

    Each impacter whose design is infeasible moves away from the tones it could not be
    made silent under; each idle impacter that responds in a step moves away from the
    nearest tone of that step.  Returns whether anything changed.
    """
    changed = False
    for _, (a, b) in design_offenders(designs, steps, assignment):
        _widen(pair_sep, assignment, a, b, sep)
        changed = True
    for fail in failures:
        if fail.kind != IDLE_RESPONSE or fail.impacter not in designs:
            continue
        active = sorted(Node(d, dr).text for d, dr in steps[fail.step].active_nodes())
        f = assignment.frequencies[fail.impacter]
        near = min(active, key=lambda a: abs(math.log(assignment.frequencies[a] / f)))
        _widen(pair_sep, assignment, fail.impacter, near, sep)
        changed = True
    return changed
