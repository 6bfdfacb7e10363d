"""plan.json: the file a plan is handed on in, declared once, written and read back.

:mod:`~planner.planfile.schema` declares every block of plan.json as a typed record
(units in the field names); the plan's pipeline writes the file through it
(:mod:`planner.planning.record`), and :mod:`~planner.planfile.reader` reads it back
through it, once, into a frozen :class:`~planner.planfile.reader.PlanRecord` and checks
it (``vibroplan yield``, ``replan``, ``trim``, ``drive``, ``layout``).
"""
