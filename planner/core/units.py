"""Unit constants: the SI value of one of each unit a config key or a report uses.

Configs carry their unit in the key (``gap_um``, ``window_ms``); they are converted to
SI once, by multiplying with these, and printed by dividing by them.
"""

UM = 1e-6       #: micrometre [m]
UM2 = 1e-12     #: square micrometre [m^2]
MM = 1e-3       #: millimetre [m]
MS = 1e-3       #: millisecond [s]
KHZ = 1e3       #: kilohertz [Hz]
MPA_S = 1e-3    #: millipascal second [Pa s]
GPA = 1e9       #: gigapascal [Pa]
UN = 1e-6       #: micronewton [N]
