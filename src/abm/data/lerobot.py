"""abm episodes <-> LeRobot datasets (``abm data export --format lerobot`` / ``abm data import``).

Writes the LeRobot **v3.0** layout (``codebase_version`` "v3.0", the layout of lerobot 0.4)::

    DS/meta/info.json                                 features (dtype, shape, names), fps, counts, paths,
                                                      frame_sampling, abm (format, frames, cameras, sha256)
    DS/meta/stats.json                                min / max / mean / std / count / q01 ... q99 per feature
    DS/meta/tasks.parquet                             task string (the instruction) -> task_index
    DS/meta/episodes/chunk-000/file-000.parquet       one row per episode: length, frame range, data and video
                                                      file and range, stats/<feature>/<stat>, and
                                                      ``abm/episode`` (JSON: task, split, seed, objects, ...)
    DS/data/chunk-CCC/file-FFF.parquet                one row per frame, one row group per episode
    DS/videos/observation.images.<camera>/chunk-CCC/file-FFF.mp4   episodes of a camera back to back

Features are named so LeRobot's policies read what they should (:mod:`abm.data.lerobot_schema`): the cameras
``observation.images.*``, the proprioceptive state ``observation.state``, the action ``action``; depth,
segmentation and calibration are ``geometry.*``, the exact TCP pose, joint positions and end-effector action
``robot.*``, keyframe labels ``keyframe.*``, none of which a LeRobot policy takes as state.

Dense exports (episodes recorded with ``abm data generate --dense``; the default when every episode has its
trajectory) have one frame per control tick at the recording rate (``fps``; ``timestamp = frame_index / fps``)
and H.264 videos (yuv420p, lossy). Keyframe exports have one frame per keyframe: ``frame_sampling:
"keyframes"`` in ``info.json``, ``keyframe.is_keyframe`` true on every frame, the camera images as PNG in the
parquet (LeRobot's ``image`` dtype: no video, whose frames are found by time, has to pretend a frame rate),
``timestamp`` the time of the keyframe in the recording when the episode was recorded ``--dense`` and NaN
otherwise, and ``fps`` 1, which LeRobot needs and uses as an index step only (a ``delta_timestamps`` offset of
``k`` is the ``k``-th next keyframe).

The writer is :mod:`abm.data.lerobot_export` (:func:`export_lerobot`: how files are split, what is checked before
anything is written), the reader :mod:`abm.data.lerobot_import` (:func:`import_lerobot`: the checks of a dataset,
the containment of what it writes); this module names both, with the schema's names users need.
"""

from __future__ import annotations

from abm.data.lerobot_export import ExportReport, export_lerobot
from abm.data.lerobot_import import import_lerobot
from abm.data.lerobot_schema import DATA_FILE, EPISODES_FILE, EXPORT_MARKER, LeRobotFormatError

__all__ = ["DATA_FILE", "EPISODES_FILE", "EXPORT_MARKER", "ExportReport", "LeRobotFormatError", "export_lerobot",
           "import_lerobot"]
