"""The benchmark CLIP's trainer: renders an image-text set from the simulator (:mod:`.data`, captions from
:mod:`.captions`) and fine-tunes a small CLIP on it (:mod:`.train`); run it with ``abm clip train``.

Only the command line (:mod:`abm.cli`), tests and benchmarks import this package; the library loads a trained
folder like any CLIP model (:func:`abm.grounding.clip.load_clip`). It uses the simulator's public API only.
"""
