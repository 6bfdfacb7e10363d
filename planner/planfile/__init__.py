"""plan.json: the file a plan is handed on in, declared and read back.

:mod:`~planner.planfile.reader` declares the part of plan.json the commands that take a
plan use (``vibroplan yield``, ``replan``, ``trim``, ``drive``, ``layout``), reads it
once into a frozen :class:`~planner.planfile.reader.PlanRecord` and checks it; the
plan's pipeline writes it (:mod:`planner.planning.record`).
"""
