"""Inputs read safely, outputs that never destroy a user's data, and the version string.

Every command that reads or writes goes through this package, the library as well as
the CLI.  One module per concept:

- :mod:`~planner.files.inputs`: :func:`read_input` reads a regular file of at most
  :data:`planner.runtime.limits.MAX_INPUT_BYTES` (not a device such as /dev/zero, not a FIFO
  that would block forever).
- :mod:`~planner.files.marks`: the records that say which command wrote an output (the
  :data:`MARKER` of an output folder, the :data:`REGISTRY` beside output files).
- :mod:`~planner.files.targets`: where an output may go at all (its folder exists and
  is writable; never one of the command's inputs).
- :mod:`~planner.files.swap`: temporaries beside a target, the lock on it, signals held
  back during a swap, and what dead runs left (:func:`clean_stale`).
- :mod:`~planner.files.folders` and :mod:`~planner.files.files`: the checks and the atomic
  writers of output folders and of output files.
- :mod:`~planner.files.version`: :func:`version_string`.

Output folders (``vibroplan plan --out DIR`` and the like):

- :func:`check_output_folder` refuses, before any work, a folder that this command may
  not replace: the current directory or one of its ancestors, a folder holding an input
  file, a file, a folder inside another vibroplan output folder, a non-empty folder that
  no vibroplan run wrote, one that another command wrote (the :data:`MARKER` file every
  run leaves records which), or one holding files this command did not write (the
  marker lists the files it wrote, with their SHA-256) -- all but the first three
  unless ``force``.
- :func:`output_folder` writes a folder beside the target and swaps it in atomically at
  the end (rename the old one aside, rename the new one in, remove the old one), under
  a lock that makes a concurrent writer of the same folder fail at once with a clear
  message instead of corrupting it.  Taking the lock also cleans what a dead run of the
  same target left (:func:`clean_stale`).

Output files (``--out FILE``, ``--plot FILE``, a drive file's JSON sidecar):

- :func:`check_output_file` refuses, before any work, a file that is one of the
  command's inputs (even with ``force``), lies inside a vibroplan output folder, or
  exists and was not written by this command (the :data:`REGISTRY` file of its folder
  records which command wrote which file, with its SHA-256) -- the last two unless
  ``force``.
- :func:`output_files` writes files beside their targets and moves each into place when
  the block succeeds, recording them in the registry.

On any exception, ``KeyboardInterrupt`` and the CLI's signal exceptions included,
the temporaries are removed and the targets are left as they were.

The names below are the package's API (the CLI, the library's writers and the tests
import them from here); the modules' other functions are its internals.
"""

from planner.files.files import check_output_file, output_files
from planner.files.folders import check_output_folder, output_folder
from planner.files.inputs import check_input, read_input
from planner.files.marks import MARKER, REGISTRY, folder_marker, written_by
from planner.files.swap import clean_stale
from planner.files.targets import check_not_input, check_parent
from planner.files.version import version_string

__all__ = ["MARKER", "REGISTRY", "check_input", "check_not_input", "check_output_file",
           "check_output_folder", "check_parent", "clean_stale", "folder_marker",
           "output_files", "output_folder", "read_input", "version_string", "written_by"]
