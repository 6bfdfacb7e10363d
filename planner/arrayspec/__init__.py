"""The array spec: devices on a grid, process, drive, design and scenes (YAML).

Devices are named like a well plate: rows A, B, ... and columns 1, 2, ... (A1 ... E5 on
the default 5 x 5 array).  Every device has a forward and a backward impacter pair.
A *scene* is a named sequence of steps; a step lists which devices move forward and
which backward, for how long (or how far), or where each device must end
(``targets_um``, docs/targets.md); every other device must stay idle.  With
``independent: true`` (the default when no scenes are given) every impacter must also
be drivable on its own, which adds one implicit step per impacter.

Selectors in a step's ``forward``/``backward`` lists: a device id (``C3``), a row
letter (``B`` = B1 ... B5), a column number as text (``"3"`` = A3 ... E3), or ``all``.

Validation names the field and the YAML line: ``drive.band_hz: band_hz[1] must be
greater than band_hz[0] (line 14)``.

One module per job: :mod:`~planner.arrayspec.schema` (the sections and fields, their units
and defaults), :mod:`~planner.arrayspec.steps` (scenes resolved to :class:`Step` s),
:mod:`~planner.arrayspec.load` (:func:`load_spec`: YAML in, errors on their lines, the
embedded default spec) and :mod:`~planner.arrayspec.channels` (the channels between two tones; the channel
grid is :func:`planner.manufacturability.channel_grid`).  The
names below are the spec's API: the CLI, the planner's stages and the tests import
them from ``planner.arrayspec`` (the other sections' models are in
:mod:`~planner.arrayspec.schema`).
"""

from planner.arrayspec.channels import separation_for_bandwidth
from planner.arrayspec.load import LoadedSpec, default_spec_path, load_spec
from planner.arrayspec.schema import ArraySpec, FabricationSpec, Tolerance, TrimSpec, WaferSpec
from planner.arrayspec.steps import DEFAULT_MAX_BURST_S, Step, resolve_steps

__all__ = ["DEFAULT_MAX_BURST_S", "ArraySpec", "FabricationSpec", "LoadedSpec", "Step",
           "Tolerance", "TrimSpec", "default_spec_path", "load_spec",
           "WaferSpec",
           "resolve_steps", "separation_for_bandwidth"]
