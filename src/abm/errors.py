"""The errors abm raises for what its user can fix, and nothing else.

Every error of this module says in its message what went wrong and how to fix it (the file or option it is
about, the values it expected). The command line (:func:`abm.cli.main`) prints an :class:`AbmError` as one
``abm: error: MESSAGE`` line with exit code 2; any other exception is a bug: it keeps its traceback, followed
by a line asking to report it.

* :class:`ConfigError`: what the user asked for cannot be done as asked: an option's value (a path that is
  missing or of the wrong kind included), a setting of a recipe, experiment spec, robot or split file, a name
  no registry holds, an instruction the parser refuses;
* :class:`DataError`: a file or folder abm reads does not hold what it should: damaged, of another format or
  version, incomplete, not matching its checksum or schema (episode stores, datasets, the zoo's index, outcome
  logs); :class:`CheckpointError` (a :class:`DataError`): a checkpoint or run folder no policy can be built
  from, or one that does not fit the model or the command;
* :class:`OutputError`: where the command writes cannot take its output: a file or a symbolic link in the way,
  a full disk, no permission, a folder another process writes into;
* :class:`RefusedError`: the robot refused to act (a keyframe outside its motion limits, no target to act on):
  nothing moved;
* :class:`ExternalError`: something outside abm that the command needs is missing or failed: an optional
  package, CUDA, Chromium, CLIP weights, simulator assets, a Ray cluster, a device, a job the command started
  (its log says why).

Each also derives from the built-in exception it replaced (``ValueError``; ``RuntimeError`` for
:class:`ExternalError`), so code that catches the built-in still catches it; the errors of the packages are
subclasses of these (``abm.data.episode_store.EpisodeFormatError`` is a :class:`DataError`, ...).
"""

from __future__ import annotations


class AbmError(Exception):
    """An error the user can fix; its message says what and how (printed as one ``abm: error:`` line)."""


class ConfigError(AbmError, ValueError):
    """An option, a setting of a recipe, spec, robot or split file, a name or an instruction that cannot be used."""


class DataError(AbmError, ValueError):
    """A file or folder abm reads that is damaged, of another format or version, incomplete or does not match."""


class CheckpointError(DataError):
    """A checkpoint or run folder no policy can be built from, or one that does not fit the model or command."""


class OutputError(AbmError, ValueError):
    """The command's output cannot be written where it was asked to go; nothing was left half-written."""


class RefusedError(AbmError, ValueError):
    """The robot refused to act on a keyframe or an instruction; nothing moved."""


class ExternalError(AbmError, RuntimeError):
    """Something outside abm the command needs is missing or failed (a package, a device, a cluster, a job)."""
