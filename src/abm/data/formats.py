"""Dataset formats of ``abm data export`` / ``abm data import``: the registry :data:`DATASET_FORMATS` (light: the
command line's ``--format`` choices are its names; the readers and writers are imported when a command runs).

A format is one :class:`DatasetFormat` entry naming its writer and reader as ``"module:callable"``:

* the writer, ``export(data, out, **options) -> report``: every episode of the store ``data`` into a new (or empty)
  dataset folder ``out``; ``options`` are the ``abm data export`` options the entry lists in ``export_options``
  (those given on the command line), and the report has ``summary() -> str`` (one line: what was written);
* the reader, ``import_(dataset, out, overwrite=, task=, split=) -> list[Path]``: the dataset's episodes as abm
  episode files under ``out`` (``OUT/<task>/<split>/episode_<N>.h5``), refusing to replace files without
  ``overwrite``; ``task`` and ``split`` name them for a dataset that does not.

**Adding a format**: its module (the writer and the reader) and its :func:`register_format` entry here.
"""

from __future__ import annotations

from dataclasses import dataclass

from abm.registry import Registry


@dataclass(frozen=True)
class DatasetFormat:
    """One dataset format: an entry of :data:`DATASET_FORMATS`.

    Attributes:
        export: ``"module:callable"`` of the writer (see the module docstring).
        import_: ``"module:callable"`` of the reader.
        description: one line (``--format`` help).
        export_options: the ``abm data export`` options (by destination name) the writer takes.
        extra: the pip extra that installs its dependencies (``pip install 'abm[EXTRA]'``), named when an import
            fails.
    """

    export: str
    import_: str
    description: str
    export_options: tuple[str, ...] = ()
    extra: str | None = None


#: every dataset format, by name (``abm data export/import --format`` choices)
DATASET_FORMATS: Registry[DatasetFormat] = Registry("dataset format")


def register_format(name: str, fmt: DatasetFormat) -> DatasetFormat:
    """Add a dataset format to :data:`DATASET_FORMATS`."""
    return DATASET_FORMATS.register(name, fmt)


register_format("lerobot", DatasetFormat(
    "abm.data.lerobot_export:export_lerobot", "abm.data.lerobot_import:import_lerobot",
    "LeRobot v3.0 (parquet + H.264 mp4; abm's own exports come back exactly, other datasets need depth and "
    "calibration)", export_options=("frames", "crf", "data_file_mb", "video_file_mb"), extra="lerobot"))
