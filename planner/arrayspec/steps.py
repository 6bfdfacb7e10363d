"""A spec's scenes resolved to steps: device ids in each direction, durations in SI.

:func:`resolve_steps` turns every step of every scene into a :class:`Step`: its
selectors (a device id ``C3``, a row letter ``B``, a column number as text ``"3"``, or
``all``) become device ids, a ``targets_um`` step's targets become moves whose signs
say which devices move forward and which backward, and what the schema alone cannot
see is refused with the field's path and YAML line (an unknown device, one asked to
move both ways, a move beyond ``verification.max_travel_um``, a duplicate step name).
"""

from __future__ import annotations

from dataclasses import dataclass

from planner.core.errors import SpecError
from planner.arrayspec.schema import ArraySpec
from planner.files.yamlio import format_loc, line_of

#: Longest burst [s] of a ``travel_um`` step without ``duration_ms``.
DEFAULT_MAX_BURST_S = 0.1


@dataclass(frozen=True)
class Step:
    """A resolved step: device ids in each direction, duration in SI."""

    scene: str
    name: str
    index: int
    duration_s: float
    forward: tuple[str, ...]
    backward: tuple[str, ...]
    #: Travel [m] the burst is sized for (step ``travel_um``), or None.
    travel_m: float | None = None
    #: Longest burst [s] a ``travel_um`` or ``targets_um`` step may get (its
    #: ``duration_ms``), or None.
    max_duration_s: float | None = None
    #: A ``targets_um`` step's targets: (device, position [m]) in the frame of
    #: ``relative_to``, in device order; None for any other step.
    targets_m: tuple[tuple[str, float], ...] | None = None
    #: ``scene_start`` or ``previous_step`` (``targets_um`` steps).
    relative_to: str = "scene_start"
    #: (device, move [m]) of every targeted device: the spec's nominal move (its target
    #: minus its previous target); the planner replaces it by the move from where the
    #: carried-state scene simulation finds the slider when the step starts.
    moves_m: tuple[tuple[str, float], ...] = ()

    @property
    def key(self) -> str:
        return f"{self.scene}/{self.name}"

    @property
    def targets(self) -> dict[str, float]:
        """Device -> target [m] (empty unless a ``targets_um`` step)."""
        return dict(self.targets_m or ())

    @property
    def moves(self) -> dict[str, float]:
        """Device -> move [m] of a ``targets_um`` step (see ``moves_m``)."""
        return dict(self.moves_m)

    def active_nodes(self) -> set[tuple[str, str]]:
        return {(d, "forward") for d in self.forward} | {(d, "backward") for d in self.backward}


def _select(sel, ids, rows, cols, loc, lines, source):
    """The device ids one selector names (see the module docstring)."""
    sel = str(sel).strip()
    if sel.lower() == "all":
        return list(ids)
    if sel in ids:
        return [sel]
    if len(sel) == 1 and sel.upper() in rows:
        return [i for i in ids if i[0] == sel.upper()]
    if sel.isdigit() and sel in cols:
        return [i for i in ids if i[1:] == sel]
    raise SpecError(f"unknown device {sel!r} (devices are {ids[0]} ... {ids[-1]}, a row "
                    "letter, a column number or 'all')", path=format_loc(loc),
                    line=line_of(lines, loc), source=source)


def _resolve(selectors, ids, rows, cols, where, lines, source):
    out = []
    for k, sel in enumerate(selectors):
        for c in _select(sel, ids, rows, cols, where + (k,), lines, source):
            if c not in out:
                out.append(c)
    return tuple(out)


def _max_travel_m(spec: ArraySpec) -> float:
    """``verification.max_travel_um`` [m], or half the pitch."""
    ver = spec.verification
    return (ver.max_travel_um if ver.max_travel_um is not None
            else 0.5 * spec.array.pitch_um) * 1e-6


def _targets(st, base, ids, rows, cols, nominal, sized, max_travel, lines, source):
    """(targets, moves) of a ``targets_um`` step, both ((device, [m]), ...) in device
    order; updates the scene's ``nominal`` positions [m] in place.

    ``sized``: device -> the earlier step that moved it by an amount the planner
    sizes (its position in the scene frame is then unknown).
    """
    where = base + ("targets_um",)
    rel = st.relative_to or "scene_start"
    named = {}
    for key, value in st.targets_um.items():
        loc = where + (key,)
        for dev in _select(key, ids, rows, cols, loc, lines, source):
            if dev in named:
                raise SpecError(f"device {dev} is given twice (keys {named[dev][0]!r} and "
                                f"{key!r})", path=format_loc(loc), line=line_of(lines, loc),
                                source=source)
            named[dev] = (key, value * 1e-6)
    targets, moves = [], []
    for dev in [i for i in ids if i in named]:
        key, target = named[dev]
        loc = where + (key,)
        if rel == "scene_start":
            if dev in sized:
                raise SpecError(f"{dev} was moved by step {sized[dev]!r} by an amount the "
                                "planner sizes (duration_ms or travel_um), so where it is "
                                "relative to the scene start is not known: give this step "
                                "relative_to: previous_step", path=format_loc(loc),
                                line=line_of(lines, loc), source=source)
            move = target - nominal[dev]
        else:
            move = target
        if abs(move) > max_travel * (1 + 1e-12):
            raise SpecError(f"{dev}: a move of {move * 1e6:+.4g} um in one step exceeds "
                            f"verification.max_travel_um ({max_travel * 1e6:g} um); split "
                            "it over two steps or raise max_travel_um", path=format_loc(loc),
                            line=line_of(lines, loc), source=source)
        nominal[dev] += move
        targets.append((dev, target))
        moves.append((dev, move))
    if not any(m != 0.0 for _, m in moves):
        raise SpecError("a step must move at least one device: every target is where its "
                        "device already is", path=format_loc(where),
                        line=line_of(lines, where), source=source)
    return tuple(targets), tuple(moves)


def resolve_steps(spec: ArraySpec, lines=None, source=None) -> tuple[Step, ...]:
    """Resolve every scene's steps to device ids, checking ids and contradictions.

    A ``targets_um`` step's devices move forward or backward by the sign of their
    nominal move (target minus the previous target of the scene, or the target itself
    with ``relative_to: previous_step``); a move beyond the largest travel of one step
    (``verification.max_travel_um``) is refused here, naming the device.
    """
    lines = lines or {}
    ids = spec.array.device_ids()
    rows = {i[0] for i in ids}
    cols = {i[1:] for i in ids}
    max_travel = _max_travel_m(spec)
    for dev in spec.devices:
        if dev not in ids:
            loc = ("devices", dev)
            raise SpecError(f"unknown device {dev!r} (devices are {ids[0]} ... {ids[-1]})",
                            path=format_loc(loc), line=line_of(lines, loc), source=source)
    steps = []
    for scene, step_list in spec.scenes.items():
        if not step_list:
            loc = ("scenes", scene)
            raise SpecError("a scene needs at least one step", path=format_loc(loc),
                            line=line_of(lines, loc), source=source)
        names = set()
        # where each slider should be relative to the scene start [m], as the targets
        # ask, and the devices an earlier step moved by an amount the planner sizes
        nominal = {i: 0.0 for i in ids}
        sized = {}
        for i, st in enumerate(step_list):
            base = ("scenes", scene, i)
            if st.name in names:
                raise SpecError(f"duplicate step name {st.name!r} in scene {scene!r}",
                                path=format_loc(base + ("name",)),
                                line=line_of(lines, base + ("name",)), source=source)
            names.add(st.name)
            cap = st.duration_ms * 1e-3 if st.duration_ms is not None else None
            if st.targets_um is not None:
                targets, moves = _targets(st, base, ids, rows, cols, nominal, sized,
                                          max_travel, lines, source)
                fwd = tuple(d for d, m in moves if m > 0)
                bwd = tuple(d for d, m in moves if m < 0)
                # the planner gates the burst (planning.targets); until then its
                # duration is its cap, or the default cap
                steps.append(Step(scene, st.name, len(steps),
                                  cap if cap is not None else DEFAULT_MAX_BURST_S, fwd, bwd,
                                  max_duration_s=cap, targets_m=targets,
                                  relative_to=st.relative_to or "scene_start",
                                  moves_m=moves))
                continue
            fwd = _resolve(st.forward, ids, rows, cols, base + ("forward",), lines, source)
            bwd = _resolve(st.backward, ids, rows, cols, base + ("backward",), lines, source)
            both = sorted(set(fwd) & set(bwd))
            if both:
                loc = base + ("backward",)
                raise SpecError(f"device(s) {', '.join(both)} cannot move both forward and "
                                "backward in one step", path=format_loc(loc),
                                line=line_of(lines, loc), source=source)
            if not fwd and not bwd:
                raise SpecError("a step must move at least one device", path=format_loc(base),
                                line=line_of(lines, base), source=source)
            sized.update({d: st.name for d in fwd + bwd})
            travel = st.travel_um * 1e-6 if st.travel_um is not None else None
            # a travel_um step gets its burst from the planner (planning.motion); until
            # then its duration is its cap, or the default cap
            duration = cap if cap is not None else DEFAULT_MAX_BURST_S
            steps.append(Step(scene, st.name, len(steps), duration, fwd, bwd,
                              travel_m=travel, max_duration_s=cap if travel else None))
    return tuple(steps)
